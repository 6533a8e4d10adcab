"""Layer plumbing of the widgets: metadata keys, image-layer choices and snapshots, aligned
transforms, and what a layer says about its camera (motion, focal length)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from napari.layers import Image, Layer

from ..core.camera import DEFAULT_FOCAL_35MM, Intrinsics
from ..core.io import exif_focal_35mm
from ..core.motion import CameraMotion

__all__ = [
    "ESTIMATE_KEY",
    "MOTION_KEY",
    "PROFILES_KEY",
    "SOURCE_KEY",
    "default_focal_px",
    "focal_from_layer",
    "image_layers",
    "image_shape",
    "motion_from",
    "resampled_kwargs",
    "snapshot_image",
    "spatial_kwargs",
]

#: Layer-metadata key of a summary of an estimation run (method, parameters, gamma, timing).
ESTIMATE_KEY = "edgecme_estimate"
#: Layer-metadata key of a camera motion: the JSON dict of ``CameraMotion.to_dict()``
#: (a dict, not the object, so that it survives saving the layer).
MOTION_KEY = "edgecme_motion"
#: Layer-metadata key of the edge profiles a Shapes layer shows (``EdgeProfiles``).
PROFILES_KEY = "edgecme_profiles"
#: Layer-metadata key naming the image layer a result was computed from.
SOURCE_KEY = "edgecme_source"


def image_layers(viewer) -> list[tuple[str, Image]]:
    """The viewer's image layers the engine can work on: one 2-D gray or RGB(A) plane.

    Returned as ``(name, layer)`` pairs, the form magicgui combo boxes take.
    """
    return [(layer.name, layer) for layer in viewer.layers
            if isinstance(layer, Image) and not layer.multiscale and layer.ndim == 2]


def snapshot_image(layer: Image) -> np.ndarray:
    """A private copy of a 2-D gray or RGB image layer's pixels, taken on the main thread.

    The worker thread computes on this copy, so the layer can change (or be deleted)
    while a run is under way. An alpha channel is dropped.

    Raises
    ------
    ValueError
        If the layer is not one 2-D plane (gray, RGB or RGBA).
    """
    if layer.multiscale:
        raise ValueError(f"layer {layer.name!r} is multiscale; pick a single-resolution image")
    data = np.array(layer.data, copy=True)
    if layer.rgb and data.ndim == 3 and data.shape[-1] in (3, 4):
        return np.ascontiguousarray(data[..., :3])
    if data.ndim != 2:
        raise ValueError(f"layer {layer.name!r} must be a 2-D gray or RGB image; "
                         f"got data of shape {data.shape}")
    return data


def image_shape(layer: Image) -> tuple[int, int]:
    """``(rows, cols)`` of a 2-D gray or RGB image layer."""
    shape = layer.data.shape
    return (int(shape[0]), int(shape[1]))


def spatial_kwargs(layer: Layer) -> dict:
    """The transform of ``layer`` as layer-constructor keywords, for aligned results."""
    return {"scale": tuple(layer.scale), "translate": tuple(layer.translate),
            "rotate": np.asarray(layer.rotate), "shear": np.asarray(layer.shear)}


def resampled_kwargs(layer: Layer, shape) -> dict:
    """Transform that lays an array of ``shape`` over ``layer`` (a resized copy of its data).

    A resized copy maps pixel centres as ``p_image = (p + 1/2) * f - 1/2`` with
    ``f = image_size / copy_size`` per axis; composing that with the layer's own
    scale and translate keeps the copy exactly over the image.
    """
    full = np.asarray(image_shape(layer), float)
    factor = full / np.asarray(shape[:2], float)
    scale = np.asarray(layer.scale, float)
    translate = np.asarray(layer.translate, float) + scale * (0.5 * factor - 0.5)
    return {"scale": tuple(scale * factor), "translate": tuple(translate),
            "rotate": np.asarray(layer.rotate), "shear": np.asarray(layer.shear)}


def motion_from(obj) -> CameraMotion:
    """The camera motion held by a layer (its metadata), a dict or a ``CameraMotion``.

    Raises
    ------
    ValueError
        One line naming what is missing or malformed.
    """
    if isinstance(obj, CameraMotion):
        return obj
    if isinstance(obj, Layer):
        value = obj.metadata.get(MOTION_KEY)
        if value is None:
            raise ValueError(f"layer {obj.name!r} holds no camera motion in its metadata")
        try:
            return motion_from(value)
        except ValueError as err:
            raise ValueError(f"layer {obj.name!r}: {err}") from None
    if isinstance(obj, dict):
        return CameraMotion.from_dict(obj)
    raise ValueError(f"expected a camera motion; got {type(obj).__name__}")


def focal_from_layer(layer: Image) -> tuple[float | None, str]:
    """The focal length (pixels) of the camera that took an image layer, and where it came from.

    Looked for, in order: ``metadata["focal_px"]``; a 35 mm-equivalent focal length
    ``FocalLengthIn35mmFilm`` in ``metadata`` or ``metadata["exif"]`` (as napari
    readers may store EXIF); the EXIF of the file the layer was opened from. The
    35 mm value converts as in :meth:`~napari_edgecme.core.camera.Intrinsics.from_image_shape`,
    ``f = f35 / 36 * max(rows, cols)`` (36 mm: the width of a 35 mm frame).

    Returns
    -------
    focal_px : float or None
        None when nothing is known: the engine then assumes its 35 mm-equivalent default.
    source : str
        Human-readable origin, for the widget's hint.
    """
    shape = image_shape(layer)
    meta = layer.metadata or {}
    value = _positive(meta.get("focal_px"))
    if value is not None:
        return value, "layer metadata (focal_px)"
    exif = meta.get("exif") if isinstance(meta.get("exif"), dict) else {}
    for where, table in (("layer metadata", meta), ("layer EXIF metadata", exif)):
        f35 = _positive(table.get("FocalLengthIn35mmFilm"))
        if f35 is not None:
            return _focal_px(f35, shape), f"{where} ({f35:g} mm equivalent)"
    path = getattr(layer.source, "path", None)
    if path:
        f35 = exif_focal_35mm(path)
        if f35 is not None:
            return _focal_px(f35, shape), f"EXIF of {Path(path).name} ({f35:g} mm equivalent)"
    return None, f"default ({DEFAULT_FOCAL_35MM:g} mm equivalent)"


def default_focal_px(shape) -> float:
    """The engine's focal length for an image without EXIF (35 mm-equivalent default)."""
    return Intrinsics.from_image_shape(shape).focal_px


def _focal_px(f35: float, shape) -> float:
    """A 35 mm-equivalent focal length in pixels of an image of ``shape``, as the engine
    converts it."""
    return Intrinsics.from_image_shape(shape, focal_35mm=f35).focal_px


def _positive(value) -> float | None:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) and out > 0 else None
