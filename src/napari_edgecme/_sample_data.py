"""napari sample data: blurred images to try the widgets on.

* :func:`synthetic_shake` -- scikit-image's "camera" photo shaken by a random
  spatially varying (3-D rotation) camera motion, rendered exactly; the true motion
  is in the blurred layer's ``metadata["edgecme_motion"]`` (motion-file dict), so the
  "Deconvolution" widget can use it and estimates can be compared with it. The
  sharp photo comes along as a hidden layer.
* :func:`edge_scene_shake` -- an edge-rich synthetic scene like the paper's Fig. 3
  (discs and polygons with straight step edges), shaken the same way.
* :func:`clock_motion` -- the real motion-blurred photo scikit-image ships
  (``clock_motion.png``); its motion is unknown.

Each returns a list of napari ``LayerData`` tuples. Nothing here imports Qt.
"""

from __future__ import annotations

import os

from .core.synth import SyntheticCase, edge_scene, make_case, sample_image

__all__ = ["clock_motion", "edge_scene_shake", "synthetic_shake"]

_MOTION_KEY = "edgecme_motion"  # as in napari_edgecme._widgets._layers (no Qt import here)


def _layers(case: SyntheticCase, title: str, description: str) -> list[tuple]:
    motion = case.motion
    blurred_meta = {
        _MOTION_KEY: motion.to_dict(),
        "focal_px": motion.intrinsics.focal_px,
        "description": description,
        "blur_extent_px": case.extent,
        "noise_sigma": case.noise,
    }
    return [
        (case.sharp, {"name": f"{title} (sharp)", "visible": False, "colormap": "gray",
                      "contrast_limits": (0.0, 1.0),
                      "metadata": {"description": f"sharp original of {title!r}"}}, "image"),
        (case.blurred, {"name": f"{title} (synthetic shake)", "colormap": "gray",
                        "contrast_limits": (0.0, 1.0), "metadata": blurred_meta}, "image"),
    ]


def synthetic_shake() -> list[tuple]:
    """The "camera" photo (256 px) blurred by a spatially varying 3-D camera rotation.

    Blur extent about 13 px, 1% noise, 8-bit quantisation; seeded (always the same).
    The true motion is in the blurred layer's metadata.
    """
    case = make_case(sample_image("camera", 256), "rotation", extent=13.0, noise=0.01,
                     rng=2017, name="camera")
    return _layers(case, "camera", "scikit-image 'camera' shaken by a synthetic 3-D camera "
                   "rotation; metadata['edgecme_motion'] is the true motion")


def edge_scene_shake() -> list[tuple]:
    """An edge-rich synthetic scene (256 px, like the paper's Fig. 3), blurred by camera shake.

    Straight and circular step edges on flat ground: many clean edge profiles. The true
    (rotation) motion is in the blurred layer's metadata.
    """
    case = make_case(edge_scene((256, 256), rng=3), "rotation", extent=13.0, noise=0.01,
                     rng=2017, name="edge scene")
    return _layers(case, "edge scene", "synthetic edge scene shaken by a synthetic 3-D "
                   "camera rotation; metadata['edgecme_motion'] is the true motion")


def clock_motion() -> list[tuple]:
    """scikit-image's real motion-blurred photo of a clock (``clock_motion.png``, 300x400)."""
    import skimage.data

    from .core.io import read_image

    path = os.path.join(os.path.dirname(skimage.data.__file__), "clock_motion.png")
    image = read_image(path)  # (300, 400) uint8, gray
    return [(image, {"name": "clock (motion blur)", "colormap": "gray",
                     "metadata": {"description": "real motion-blurred photo shipped with "
                                                 "scikit-image (clock_motion.png); motion "
                                                 "unknown", "source_file": path}},
             "image")]
