"""The "Edge profiles" widget: detect, inspect, pick and export edge profiles.

Edge profiles (paper §2) are the alpha mattes of blurred straight step edges,
sampled along the edge normal; their derivatives are Radon slices of the local
PSFs (Eq. 11), the measurements EpAlone and Xu+Ep fit the camera motion to.

For an image layer the widget keeps two layers in step with one
:class:`~napari_edgecme.core.edges.EdgeProfiles` set:

* a Shapes layer ``"<image> edge profiles"``: one line across each edge (centroid
  plus/minus the sampling window along the normal), coloured by quality; it holds
  the profile set in ``metadata["edgecme_profiles"]`` (in shape order), which is
  what the "Camera motion" widget reads;
* a Points layer ``"<image> profile centroids"`` at the centroids (derived, redrawn
  from the set).

Editing the Shapes layer edits the set: a line drawn across an edge is measured by
:func:`~napari_edgecme.core.edges.profile_along_line` and kept (redrawn centred on
its centroid) or refused with the reason as a notification; deleting lines deletes
their profiles. The docked plot shows the selected profiles (or all of them) and
their derivatives.

The "gamma" choice (:class:`._gamma.GammaControl`, as in the "Camera motion" and
"Deconvolution" widgets: linear, the default for layers; sRGB; a power law; auto from
the layer's source file) says how the layer's values encode light: profiles are taken
from the image in linear light, where a blurred step is the PSF's integral (on sRGB
values it is bent). Lines drawn by hand are measured in the same light as the set they
join. "Max blur" on auto is measured from the image in the worker
(:func:`~napari_edgecme.core.blur_size.measure_blur_extent`, then
:func:`~napari_edgecme.core.blur_size.max_blur_for`, as the engine does when estimating);
the status line says what was found. The Shapes layer's
``metadata["edgecme_profile_settings"]`` records the max blur, the measurement, and the
curve and why (``gamma``, ``gamma_reason``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import napari
import numpy as np
from magicgui.widgets import ComboBox
from napari.layers import Image, Points, Shapes
from napari.utils.colormaps import ensure_colormap
from napari.utils.notifications import show_error, show_info, show_warning
from qtpy.QtCore import QTimer
from qtpy.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)
from superqt import QCollapsible

from ..core._validation import as_rng, first_line
from ..core.blur_size import BlurSize, resolve_max_blur
from ..core.edges import EdgeProfiles, extract_edge_profiles, profile_along_line
from ..core.estimate import default_max_blur
from ..core.photometry import Gamma, parse_gamma
from ..core.progress import Progress
from ._dock import Connections, dock_layout
from ._gamma import GIVEN, GammaControl, gamma_note
from ._layers import (
    PROFILES_KEY,
    SOURCE_KEY,
    image_layers,
    image_shape,
    snapshot_image,
    spatial_kwargs,
)
from ._max_blur import MaxBlurControl, measured_note
from ._plots import deferred_draw, plot_canvas
from ._runner import RunControls

__all__ = ["SETTINGS_KEY", "Detected", "EdgeProfilesWidget", "iter_detect"]

logger = logging.getLogger(__name__)

#: Metadata key of the origin of each profile, ``"detected"`` or ``"hand"`` (shape order).
ORIGIN_KEY = "edgecme_profile_origin"
#: Metadata key of how the set was taken: ``{"max_blur", "blur_size", "gamma",
#: "gamma_reason"}`` (``blur_size``: what auto measured, else None).
SETTINGS_KEY = "edgecme_profile_settings"
_ROLE_KEY = "edgecme_role"
_CENTROIDS_ROLE = "profile centroids"
_QUALITY_CMAP = "viridis"
_DRAW_COLOUR = "#ff8c00"  # a line being drawn, before it is measured
_MAX_PLOTTED = 60


@dataclass(frozen=True)
class Detected:
    """What :func:`iter_detect` returns.

    Attributes
    ----------
    profiles : EdgeProfiles
    max_blur : float
        The max blur they were extracted with (px).
    blur_size : BlurSize or None
        What was measured when no max blur was given.
    """

    profiles: EdgeProfiles
    max_blur: float
    blur_size: BlurSize | None = None


def iter_detect(image: np.ndarray, max_blur: float | None = None, rng=0,
                curve: Gamma | None = None):
    """:func:`extract_edge_profiles` in the engine's generator protocol.

    A generator, for the worker thread. ``image`` (its values as stored) is decoded
    through ``curve`` first (None: taken as linear light). With ``max_blur`` None it is
    measured from the image as the engine does when estimating
    (:func:`~napari_edgecme.core.blur_size.measure_blur_extent` on its own stream of
    random numbers, then :func:`~napari_edgecme.core.blur_size.max_blur_for`) -- except
    on an image too small for the default max blur, which gets that default (and the
    extraction says it is too small). Detection is one call that takes a fraction of a
    second on photos of common size, so it reports once; a cancel is honoured when it
    returns. Returns a :class:`Detected`.
    """
    work = image if curve is None or curve.is_linear else curve.decode(image)
    rng = as_rng(rng)
    size, step, steps = None, 0, 1
    if max_blur is None:
        shape = work.shape[:2]
        if default_max_blur(shape) <= min(shape) / 2:  # else too small: no measuring
            step, steps = 1, 2
            yield Progress("profiles", 0, steps,
                           "measuring the blur size from the edge profiles")
        max_blur, size = resolve_max_blur(work, None, rng=rng)
    yield Progress("profiles", step, steps, "detecting edge profiles")
    profiles = extract_edge_profiles(work, max_blur, rng=rng)
    yield Progress("profiles", steps, steps, f"{len(profiles)} edge profiles")
    return Detected(profiles, float(max_blur), size)


def _measured(pixels, start, end, max_blur: float):
    """The profile of a hand-drawn line (:func:`profile_along_line`), or None and the
    one-line reason it was refused."""
    try:
        one = profile_along_line(pixels, start, end, max_blur=max_blur)
    except ValueError as err:
        return None, first_line(err)
    return (one, None) if len(one) else (None, one.reason)


@dataclass
class _ProfileLayers:
    """The layers that show one profile set."""

    shapes: Shapes
    image: Image
    points: Points | None = None

    @property
    def profiles(self) -> EdgeProfiles:
        return self.shapes.metadata[PROFILES_KEY]

    @property
    def origins(self) -> list[str]:
        return list(self.shapes.metadata.get(ORIGIN_KEY, ["detected"] * len(self.profiles)))

    @property
    def curve(self) -> Gamma:
        """The transfer curve the set was taken through (linear if not recorded)."""
        settings = self.shapes.metadata.get(SETTINGS_KEY) or {}
        try:
            curve = parse_gamma(settings.get("gamma", "linear"))
        except ValueError:
            curve = Gamma.linear()
        return curve if isinstance(curve, Gamma) else Gamma.linear()


def profile_lines(profiles: EdgeProfiles) -> np.ndarray:
    """The line drawn for each profile: its sampling window across the edge, (n, 2, 2).

    From ``centroid - R n`` to ``centroid + R n`` (``n`` the unit normal as
    ``(drow, dcol)``, ``R`` the half-length of the profile's offsets), in the
    image's pixel coordinates ``(row, col)``.
    """
    if len(profiles) == 0:
        return np.zeros((0, 2, 2))
    half = 0.5 * float(profiles.offsets[-1] - profiles.offsets[0])
    centre = profiles.centroids[:, None, :]
    step = half * profiles.normals[:, None, :]
    return np.concatenate([centre - step, centre + step], axis=1)


class EdgeProfilesWidget(QWidget):
    """Detect edge profiles, edit them by hand, plot and export them.

    Parameters
    ----------
    viewer : napari.viewer.Viewer
        The viewer (or a :class:`napari.components.ViewerModel`) whose layers the
        widget reads and writes.
    """

    def __init__(self, viewer: napari.viewer.Viewer, parent: QWidget | None = None):
        super().__init__(parent)
        self._viewer = viewer
        self._attached: list[_ProfileLayers] = []
        self._current: _ProfileLayers | None = None
        self._rendering = False
        self._reconciling = False
        self._pending: list[Shapes] = []
        self._connections = Connections(self)

        self.image_combo = ComboBox(label="image", choices=self._image_choices)
        self.image_combo.native.setToolTip("2-D gray or RGB image layer to take profiles from")
        self.max_blur = MaxBlurControl(self.image_combo)
        self.gamma = GammaControl(self.image_combo)
        self.controls = RunControls(
            self, "Edge profiles", run_text="Detect",
            run_tip="Find straight edges and measure how each is blurred across (edge "
                    "profiles); runs in the background",
            cancel_tip="Stop the detection; nothing changes")
        self.detect_button = self.controls.run_button
        self.cancel_button = self.controls.cancel_button
        self.status = self.controls.status
        self.runner = self.controls.runner
        self.pick_button = QPushButton("Pick by hand")
        self.pick_button.setToolTip("Draw lines across straight edges, with flat ground on "
                                    "both sides; delete lines to drop profiles")
        self.export_button = QPushButton("Export JSON…")
        self.export_button.setToolTip("Save the profile set shown below as a JSON file")
        self.count_label = QLabel("no profiles")
        self.count_label.setWordWrap(True)
        self.count_label.setToolTip(
            "Confidence: the chance that a profile matches the true blur (calibrated on "
            "natural photos with known shake). Orientations: a profile sees the blur only "
            "across its edge, so motion along edges of one direction is not seen; "
            "balance 0 = all edges parallel, 1 = evenly spread. Cells: where in the "
            "image (3x3) the profiles are.")
        self.plot_caption = QLabel("")
        self.plot_caption.setWordWrap(True)
        self.canvas, self._axes = plot_canvas(viewer, 2, height=2.2)
        self._redraw = deferred_draw(self.canvas) if self._axes else (lambda: None)
        self.canvas.setToolTip(
            "Left: each edge profile, the blurred step from dark (0) to bright (1) across "
            "the edge (alpha matte, Eq. 1). Right: its slope, which is a slice of the "
            "local blur (PSF) across the edge (a Radon projection, Eq. 11)")
        self.plot_section = QCollapsible("Plot: profiles and their slopes")
        plots = QWidget()
        plots_layout = QVBoxLayout(plots)
        plots_layout.setContentsMargins(0, 0, 0, 0)
        plots_layout.addWidget(self.plot_caption)
        plots_layout.addWidget(self.canvas)
        self.plot_section.addWidget(plots)
        self.plot_section.expand(animate=False)

        form = QFormLayout()
        form.addRow("image", self.image_combo.native)
        form.addRow("gamma", self.gamma)
        form.addRow("max blur", self.max_blur)
        edit_row = QHBoxLayout()
        edit_row.addWidget(self.pick_button)
        edit_row.addWidget(self.export_button)
        layout = QVBoxLayout()
        layout.addLayout(form)
        layout.addWidget(self.controls)
        layout.addWidget(self.count_label)
        layout.addLayout(edit_row)
        layout.addWidget(self.plot_section)
        layout.addStretch(1)
        dock_layout(self, layout)

        self.detect_button.clicked.connect(self.detect)
        self.pick_button.clicked.connect(self.pick_by_hand)
        self.export_button.clicked.connect(lambda: self.export())
        self.image_combo.changed.connect(self._on_image_changed)
        self._connections.connect(viewer.layers.selection.events.active, self._on_active_layer)
        self.reset_choices()
        self._refresh_view()

    # -- choices ---------------------------------------------------------------------------
    def _image_choices(self, _widget=None):
        return image_layers(self._viewer)

    def reset_choices(self, *_args) -> None:
        """Refresh the layer choices (napari calls this when layers change)."""
        self.image_combo.reset_choices()
        self._sync_attached()
        self._follow_image(self.image_combo.value)

    def _on_image_changed(self, layer) -> None:
        self.runner.clear_status()  # it described the previous image
        self._follow_image(layer)

    def _follow_image(self, layer) -> None:
        """Show the profile set of the chosen image (or none): never another image's."""
        rec = None if layer is None else self._record_for_image(layer)
        if rec is not self._current:
            self._current = rec
            self._refresh_view()

    def _on_active_layer(self, event=None) -> None:
        rec = self._record_for_shapes(self._viewer.layers.selection.active)
        if rec is not None and rec.image in [layer for _name, layer in self._image_choices()]:
            self.image_combo.value = rec.image  # shows its set via _on_image_changed
            self._set_current(rec)

    # -- actions ---------------------------------------------------------------------------
    def detect(self) -> None:
        """Detect edge profiles in the chosen image, in a worker thread."""
        image = self.image_combo.value
        if image is None:
            self.runner.refuse("choose an image layer first")
            return
        try:
            data = snapshot_image(image)
            curve, reason = self.gamma.resolve(image, data)
        except ValueError as err:
            self.runner.refuse(first_line(err))
            return
        max_blur = self.max_blur.value_for(data.shape)  # None on auto: measured
        self.runner.start(iter_detect(data, max_blur, curve=curve),
                          on_result=lambda found: self._show_detected(image, found, curve,
                                                                      reason))

    def cancel(self) -> None:
        """Stop a running detection (nothing changes)."""
        self.runner.cancel()

    def pick_by_hand(self) -> None:
        """Make the chosen image's profile layer active, in line-drawing mode."""
        image = self.image_combo.value
        if image is None:
            show_error("Edge profiles: choose an image layer first")
            return
        rec = self._record_for_image(image)
        if rec is None:
            try:
                curve, reason = self.gamma.resolve(image)
            except ValueError as err:
                show_error(f"Edge profiles: {first_line(err)}")
                return
            max_blur = self.max_blur.value_or_default_for(image)
            rec = self._create_layers(
                image, EdgeProfiles.empty("no profiles picked yet",
                                          image_shape=image_shape(image), max_blur=max_blur),
                [], _settings(max_blur, None, curve, reason))
        self._set_current(rec)
        self._viewer.layers.selection.active = rec.shapes
        rec.shapes.mode = "add_line"
        show_info("Edge profiles: draw lines across straight edges (flat ground on both sides)"
                  "; select lines and press Delete to drop profiles")

    def export(self, path: str | Path | None = None) -> Path | None:
        """Save the current profile set as JSON (asks for a file name when ``path`` is None)."""
        rec = self._current
        if rec is None:
            show_error("Edge profiles: nothing to export; detect or pick profiles first")
            return None
        if path is None:
            default = f"{rec.image.name}-edge-profiles.json"
            path, _ = QFileDialog.getSaveFileName(self, "Export edge profiles", default,
                                                  "JSON files (*.json)")
            if not path:
                return None
        path = Path(path)
        try:
            rec.profiles.save(path)
        except (OSError, ValueError) as err:
            show_error(f"Edge profiles: cannot save {path}: {first_line(err)}")
            return None
        show_info(f"Edge profiles: saved {len(rec.profiles)} profiles to {path}")
        return path

    @property
    def current_layers(self) -> tuple[Shapes, Points | None] | None:
        """The Shapes and Points layers of the profile set shown by the widget."""
        rec = self._current
        return None if rec is None else (rec.shapes, rec.points)

    # -- results ---------------------------------------------------------------------------
    def _show_detected(self, image: Image, found: Detected, curve: Gamma, reason: str) -> str:
        detected = found.profiles
        settings = _settings(found.max_blur, found.blur_size, curve, reason)
        if found.blur_size is not None:
            used = measured_note(found.max_blur, found.blur_size.message)
            self.max_blur.show_measured(image, found.max_blur)
        else:
            used = f"max blur {found.max_blur:g} px"
        # the curve, unless it is the layers' default (linear, as chosen)
        if not (curve.is_linear and reason == GIVEN):
            used += f"; {gamma_note(curve, reason)}"
        rec = self._record_for_image(image)
        hand, refused = EdgeProfiles.empty("none"), []
        if rec is not None:  # hand picks survive a new detection
            keep = np.array([o == "hand" for o in rec.origins], bool)
            hand = rec.profiles.select(keep)
            if len(hand) and rec.curve != curve:  # in the light of the new set
                hand, refused = self._remeasure(image, hand, curve)
        for why in refused:
            show_warning(f"Edge profiles: a hand-picked profile was dropped: measured "
                         f"with gamma {curve} it is refused: {why}")
        if len(detected) == 0 and len(hand) == 0:
            show_warning(f"Edge profiles: no usable edge profiles in {image.name!r}: "
                         f"{detected.reason}")
            if rec is not None:
                rec.shapes.metadata[SETTINGS_KEY] = settings
                self._render(rec, detected, [])
                self._set_current(rec)
            return f"no profiles ({detected.reason}; {used})"
        profiles = EdgeProfiles.concatenate([detected, hand]) if len(hand) else detected
        origins = ["detected"] * len(detected) + ["hand"] * len(hand)
        if rec is None:
            rec = self._create_layers(image, profiles, origins, settings)
        else:
            rec.shapes.metadata[SETTINGS_KEY] = settings
            self._render(rec, profiles, origins)
        self._set_current(rec)
        return f"{len(detected)} edge profiles detected in {image.name!r} ({used})"

    def _remeasure(self, image: Image, hand: EdgeProfiles, curve: Gamma):
        """The hand-picked ``hand`` measured again along their lines, on ``image``
        decoded through ``curve``: (kept profiles, reasons of the refused ones)."""
        pixels = _linear_pixels(image, curve)
        kept, refused = [], []
        for start, end in profile_lines(hand):
            one, why = _measured(pixels, start, end, hand.max_blur)
            if one is not None:
                kept.append(one)
            else:
                refused.append(why)
        if not kept:
            return EdgeProfiles.empty("none"), refused
        return EdgeProfiles.concatenate(kept), refused

    def _create_layers(self, image: Image, profiles: EdgeProfiles, origins,
                       settings: dict) -> _ProfileLayers:
        shape = image_shape(image)
        width = max(1.0, max(shape) / 300.0)
        shapes = Shapes(ndim=2, name=f"{image.name} edge profiles", edge_width=width,
                        edge_color=_DRAW_COLOUR, face_color="transparent",
                        metadata={SOURCE_KEY: image.name, PROFILES_KEY: profiles,
                                  ORIGIN_KEY: list(origins), SETTINGS_KEY: dict(settings)},
                        **spatial_kwargs(image))
        points = _centroids_layer(image)
        # attached before they are added: adding them makes napari reset the choices,
        # which adopts profile layers it does not know yet
        rec = self._attach(shapes, image, points)
        self._viewer.add_layer(shapes)
        self._viewer.add_layer(points)
        self._render(rec, profiles, origins)
        return rec

    def _render(self, rec: _ProfileLayers, profiles: EdgeProfiles, origins) -> None:
        """Redraw both layers from ``profiles`` and store the set in the Shapes metadata."""
        origins = list(origins)
        colours = ensure_colormap(_QUALITY_CMAP).map(np.clip(profiles.quality, 0, 1))
        shapes = rec.shapes
        self._rendering = True
        try:
            shapes.selected_data = set()
            shapes.data = []
            if len(profiles):
                shapes.add_lines(list(profile_lines(profiles)), edge_color=colours)
            shapes.features = {"quality": profiles.quality, "contrast": profiles.contrast,
                               "confidence": profiles.confidence, "origin": origins}
            shapes.current_edge_color = _DRAW_COLOUR
            shapes.metadata[PROFILES_KEY] = profiles
            shapes.metadata[ORIGIN_KEY] = origins
        finally:
            self._rendering = False
        points = rec.points
        if points is None or points not in self._viewer.layers:  # deleted by the user
            points = rec.points = _centroids_layer(rec.image)
            self._viewer.add_layer(points)
        points.data = profiles.centroids
        points.features = {"quality": profiles.quality, "origin": origins}
        if len(profiles):
            points.face_color = colours

    # -- attached profile layers -------------------------------------------------------------
    def _attach(self, shapes: Shapes, image: Image, points: Points | None) -> _ProfileLayers:
        known = self._record_for_shapes(shapes)
        if known is not None:
            return known
        rec = _ProfileLayers(shapes, image, points)
        self._attached.append(rec)
        self._connections.connect(shapes.events.data, self._on_shapes_data, key=shapes)
        self._connections.connect(shapes.selected_data.events.items_changed,
                                  self._on_selection, key=shapes)
        return rec

    def _detach(self, rec: _ProfileLayers) -> None:
        self._connections.disconnect_key(rec.shapes)
        self._attached.remove(rec)
        if self._current is rec:
            self._current = None
            self._refresh_view()

    def _sync_attached(self) -> None:
        """Forget removed profile layers; adopt profile layers this widget did not create."""
        layers = list(self._viewer.layers)
        for rec in list(self._attached):
            if rec.shapes not in layers:
                self._detach(rec)
        by_name = {layer.name: layer for layer in layers}
        for layer in layers:
            if (isinstance(layer, Shapes) and self._record_for_shapes(layer) is None
                    and isinstance(layer.metadata.get(PROFILES_KEY), EdgeProfiles)):
                image = by_name.get(layer.metadata.get(SOURCE_KEY))
                if isinstance(image, Image):
                    points = next((p for p in layers if isinstance(p, Points)
                                   and p.metadata.get(_ROLE_KEY) == _CENTROIDS_ROLE
                                   and p.metadata.get(SOURCE_KEY) == image.name), None)
                    self._attach(layer, image, points)

    # layers are compared with ``==``, not ``is``: plugin code may hold napari's
    # public-only proxies of the same layer objects
    def _record_for_image(self, image: Image) -> _ProfileLayers | None:
        layers = list(self._viewer.layers)
        return next((rec for rec in self._attached
                     if rec.image == image and rec.shapes in layers), None)

    def _record_for_shapes(self, shapes) -> _ProfileLayers | None:
        if shapes is None:
            return None
        return next((rec for rec in self._attached if rec.shapes == shapes), None)

    def _set_current(self, rec: _ProfileLayers) -> None:
        self._current = rec
        self._refresh_view()

    # -- editing -----------------------------------------------------------------------------
    def _on_shapes_data(self, event) -> None:
        if self._rendering or event.action not in ("added", "removed", "changed"):
            return
        # napari is still inside its own drawing/removal code: reconcile right after it
        if not any(layer is event.source for layer in self._pending):
            self._pending.append(event.source)
        QTimer.singleShot(0, self._reconcile_pending)

    def _reconcile_pending(self) -> None:
        if self._reconciling:  # re-entered from a notification's processEvents(): later
            QTimer.singleShot(0, self._reconcile_pending)
            return
        pending, self._pending = self._pending, []
        self._reconciling = True
        try:
            for layer in pending:
                rec = self._record_for_shapes(layer)
                if rec is not None:
                    self._reconcile(rec)
        finally:
            self._reconciling = False

    def _reconcile(self, rec: _ProfileLayers) -> None:
        """Bring the profile set in line with the lines the user left in the Shapes layer.

        Lines that are still exactly where a profile drew them keep their profile;
        profiles whose line is gone are dropped; any other line (new, or moved) is
        measured with :func:`profile_along_line` and kept or refused.
        """
        old, old_origins = rec.profiles, rec.origins
        finder = _LineFinder(profile_lines(old))
        kept, picks = [], []
        for data, kind in zip(rec.shapes.data, rec.shapes.shape_type, strict=True):
            j = finder.pop(data) if kind == "line" else None
            if j is not None:
                kept.append(j)
            else:
                picks.append((np.asarray(data, float), kind))
        if not picks and kept == list(range(len(old))):
            return  # nothing changed (e.g. a line re-selected)
        accepted, refused = [], []
        if picks:  # measured in the light of the set
            image = _linear_pixels(rec.image, rec.curve)
            max_blur = old.max_blur or self.max_blur.value_or_default_for(rec.image)
            for data, kind in picks:
                if kind != "line" or len(data) != 2:
                    refused.append(f"a {kind} is not a line; draw lines across edges")
                    continue
                one, why = _measured(image, data[0], data[1], max_blur)
                if one is not None:
                    accepted.append(one)
                else:
                    refused.append(why)
        parts = [old.subset(kept), *accepted]
        profiles = EdgeProfiles.concatenate(parts)
        if len(profiles) == 0 and not profiles.reason:
            profiles = EdgeProfiles.empty("all profiles removed", old.offsets, old.image_shape,
                                          old.max_blur)
        origins = [old_origins[j] for j in kept] + ["hand"] * len(accepted)
        self._render(rec, profiles, origins)
        if accepted:  # select the new profiles, so the plot shows them
            n = len(profiles)
            self._rendering = True
            try:
                rec.shapes.selected_data = set(range(n - len(accepted), n))
            finally:
                self._rendering = False
        self._set_current(rec)
        for reason in refused:  # last: a notification may process pending events
            show_warning(f"Edge profiles: line refused: {reason}")

    def _on_selection(self, *_args) -> None:
        if not self._rendering:
            self._refresh_view()

    # -- view --------------------------------------------------------------------------------
    def _refresh_view(self) -> None:
        rec = self._current
        if rec is None:
            image = self.image_combo.value
            self.count_label.setText(
                "no profiles" if image is None else
                f"no profiles for {image.name!r} yet: Detect, or Pick by hand")
            self._plot(None, [])
            return
        profiles, origins = rec.profiles, rec.origins
        n_hand = sum(o == "hand" for o in origins)
        if len(profiles):
            conf = profiles.confidence
            trust = (f"median confidence {np.nanmedian(conf):.2f}" if np.isfinite(conf).any()
                     else f"median quality {np.median(profiles.quality):.2f}")
            self.count_label.setText(
                f"{len(profiles)} profiles in {rec.shapes.name!r}: "
                f"{len(profiles) - n_hand} detected, {n_hand} by hand; {trust}\n"
                f"{profiles.coverage_summary()}")
        else:
            self.count_label.setText(f"no profiles in {rec.shapes.name!r}")
        selected = sorted(i for i in rec.shapes.selected_data if i < len(profiles))
        self._plot(profiles, selected, origins)

    def _plot(self, profiles: EdgeProfiles | None, selected, origins=()) -> None:
        """Selected profiles in their quality colour, or all of them with the median."""
        if not self._axes:
            return
        from matplotlib.collections import LineCollection

        ax_p, ax_d = self._axes
        for ax in self._axes:
            for artist in [*ax.lines, *ax.collections]:
                artist.remove()
        fg = ax_p.xaxis.label.get_color()
        ax_p.set_title("edge profile (α, Eq. 1)", fontsize=8)
        ax_d.set_title("its slope (Eq. 11)", fontsize=8)
        ax_p.set_xlabel("offset (px)", fontsize=8)
        ax_d.set_xlabel("offset (px)", fontsize=8)
        caption = "" if profiles is None else "no profiles"
        if profiles is not None and len(profiles):
            x = profiles.offsets
            if selected:
                show = np.asarray(selected[:_MAX_PLOTTED])
                colours = ensure_colormap(_QUALITY_CMAP).map(
                    np.clip(profiles.quality[show], 0, 1))
                style = {"colors": colours, "linewidths": 1.8}
                if len(selected) == 1:
                    i = selected[0]
                    how = "picked by hand" if origins and origins[i] == "hand" else "detected"
                    caption = (f"profile {i} ({how}): quality {profiles.quality[i]:.2f}, "
                               f"contrast {profiles.contrast[i]:.2f}")
                else:
                    caption = f"{len(selected)} selected profiles"
            else:
                show = np.arange(len(profiles))
                if show.size > _MAX_PLOTTED:
                    show = show[np.linspace(0, show.size - 1, _MAX_PLOTTED).round().astype(int)]
                style = {"colors": fg, "linewidths": 0.6, "alpha": 0.3}
                ax_d.plot(x, np.median(profiles.derivatives, 0), color="#ff8c00", lw=2)
                caption = (f"all {len(profiles)} profiles, median slope in orange; "
                           "select lines to inspect them")
            for ax, curves in ((ax_p, profiles.profiles), (ax_d, profiles.derivatives)):
                segments = np.stack([np.broadcast_to(x, (show.size, x.size)), curves[show]], -1)
                ax.add_collection(LineCollection(segments, **style))
                ax.set_xlim(x[0], x[-1])
            top = float(profiles.derivatives[show].max()) if show.size else 1.0
            ax_p.set_ylim(-0.05, 1.05)
            ax_d.set_ylim(0.0, 1.08 * max(top, 1e-3))
        self.plot_caption.setText(caption)
        self._redraw()


def _settings(max_blur: float | None, blur_size: BlurSize | None, curve: Gamma,
              reason: str) -> dict:
    """The Shapes layer's :data:`SETTINGS_KEY` entry (plain data: it survives saving)."""
    return {"max_blur": None if max_blur is None else float(max_blur),
            "blur_size": None if blur_size is None else blur_size.message,
            "gamma": curve.name, "gamma_reason": reason}


def _linear_pixels(layer: Image, curve: Gamma) -> np.ndarray:
    """An image layer's pixels (alpha dropped) in linear light through ``curve``."""
    data = snapshot_image(layer)
    return data if curve.is_linear else curve.decode(data)


def _centroids_layer(image: Image) -> Points:
    """An empty Points layer for the profile centroids of ``image``, aligned with it."""
    return Points(np.zeros((0, 2)), name=f"{image.name} profile centroids",
                  size=max(3.0, max(image_shape(image)) / 100.0), border_width=0,
                  metadata={SOURCE_KEY: image.name, _ROLE_KEY: _CENTROIDS_ROLE},
                  **spatial_kwargs(image))


class _LineFinder:
    """Finds which profile drew a line (napari keeps shape vertices as float32)."""

    #: Lines whose end points are this close (px) are the same line.
    TOLERANCE = 0.01

    def __init__(self, lines: np.ndarray):
        from scipy.spatial import cKDTree

        self._lines = np.asarray(lines, float).reshape(-1, 4)
        self._tree = cKDTree(self._lines) if len(self._lines) else None
        self._used: set[int] = set()

    def pop(self, data) -> int | None:
        """Index of the unused profile line equal to ``data`` (2, 2), or None."""
        vertices = np.asarray(data, float)
        if self._tree is None or vertices.shape != (2, 2):
            return None
        for j in self._tree.query_ball_point(vertices.ravel(), self.TOLERANCE, p=np.inf):
            if j not in self._used:
                self._used.add(j)
                return int(j)
        return None
