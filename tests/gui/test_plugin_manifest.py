"""The npe2 manifest and the sample data."""

from __future__ import annotations

import numpy as np
import pytest

from napari_edgecme.core.motion import CameraMotion

pytestmark = pytest.mark.gui

PLUGIN = "napari-edgecme"


def test_the_manifest_validates_with_imports():
    """What ``npe2 validate napari-edgecme --imports`` does: schema, then every python_name."""
    from npe2 import PluginManifest

    manifest = PluginManifest.from_distribution(PLUGIN)  # validates the schema
    manifest.validate_imports()  # imports every python_name; raises if one is missing


def test_the_manifest_contributes_three_widgets_three_samples_and_menus():
    from npe2 import PluginManifest

    manifest = PluginManifest.from_distribution(PLUGIN)
    contributions = manifest.contributions
    assert [w.display_name for w in contributions.widgets] == [
        "Edge profiles", "Camera motion", "Deconvolution"]
    assert [s.key for s in contributions.sample_data] == [
        "synthetic_shake", "edge_scene", "clock_motion"]
    menus = {menu: [item.command for item in items]
             for menu, items in contributions.menus.items()}
    assert menus == {
        "napari/layers/measure": ["napari-edgecme.edge_profiles_widget",
                                  "napari-edgecme.camera_motion_widget"],
        "napari/layers/filter": ["napari-edgecme.deconvolution_widget"],
    }


@pytest.mark.parametrize("key", ["synthetic_shake", "edge_scene"])
def test_synthetic_samples_carry_their_true_motion(viewer_model, plugins, key):
    layers = viewer_model.open_sample(PLUGIN, key)
    sharp, blurred = layers
    assert sharp.name.endswith("(sharp)") and not sharp.visible
    assert blurred.name.endswith("(synthetic shake)") and blurred.visible
    assert blurred.data.shape == sharp.data.shape == (256, 256)
    assert blurred.data.dtype == np.float32
    motion = CameraMotion.from_dict(blurred.metadata["edgecme_motion"])
    assert motion.model == "rotation" and motion.image_shape == (256, 256)
    assert blurred.metadata["focal_px"] == motion.intrinsics.focal_px
    # spatially varying: the PSFs at two corners differ
    corners = motion.psf([[10, 10], [245, 245]])
    assert not np.allclose(corners[0], corners[1], atol=1e-3)
    assert np.abs(blurred.data - sharp.data).mean() > 0.01


def test_the_real_blurred_photo_loads(viewer_model, plugins):
    (layer,) = viewer_model.open_sample(PLUGIN, "clock_motion")
    assert layer.name == "clock (motion blur)"
    assert layer.data.shape == (300, 400) and layer.data.dtype == np.uint8
    assert "edgecme_motion" not in layer.metadata  # its motion is unknown
