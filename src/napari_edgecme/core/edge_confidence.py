"""How far to trust one edge profile: a calibrated confidence from its test measures.

A profile that passed every validity test can still be false to the local blur (a soft
scene edge, shading, noise). On the ``lai`` development set (natural photos, real
gyro-recorded shakes, true motion; 10,369 profiles at the true and the default max blur)
the chance that a profile's derivative matches the true PSF projection with NCC >= 0.8
was fitted by logistic regression on the measures of
:data:`~napari_edgecme.core.edge_tests.MEASURES` that carry information (the others add
nothing once these are in). Held out photo by photo, its ranking of the profiles (AUC
0.747) beats the heuristic ``quality`` score (0.723), and it is calibrated: of the
profiles given 0.86 on average, 87 % were faithful; of those given 0.56, 53 %.
``benchmarks/bench_profiles.py`` prints the calibration table of the current code.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CONFIDENCE_MODEL", "confidence"]

#: Logistic-regression weights: ``confidence = 1 / (1 + exp(-z))``,
#: ``z = sum(weight * feature)``.
CONFIDENCE_MODEL = {
    "intercept": -3.16,
    "log_snr": 1.21,  # log of the contrast-to-noise ratio: by far the strongest cue
    "no_neighbours": -0.40,  # 1 when too few neighbours of similar orientation to compare
    "flatness": -1.19,  # plateau RMS over its limit
    "width_excess": 0.58,  # variance over the blur field's limit (0.7 when not fitted)
    "relative_scale": 0.51,  # detection scale over max_blur (1, 0.5 or 0.25)
    "monotonicity": -1.23,  # largest fall in the transition over its limit
}

_NEEDED = ("snr", "agreement", "flatness", "width_excess", "scale", "monotonicity")
#: ``width_excess`` where the blur field was not fitted (its median on the lai set)
_WIDTH_EXCESS_FILL = 0.7


def confidence(measures: dict, max_blur: float | None) -> np.ndarray:
    """The calibrated confidence of each profile, (n,) in (0, 1); NaN without measures.

    Parameters
    ----------
    measures : dict of str to ndarray of shape (n,)
        :attr:`EdgeProfiles.measures` (needs ``snr``, ``agreement``, ``flatness``,
        ``width_excess``, ``scale``, ``monotonicity``).
    max_blur : float or None
        The max blur the profiles were extracted for (the scale is relative to it).
    """
    if not measures or any(k not in measures for k in _NEEDED) or not max_blur:
        n = len(next(iter(measures.values()))) if measures else 0
        return np.full(n, np.nan)
    m = {k: np.asarray(measures[k], float) for k in _NEEDED}
    excess = m["width_excess"]
    w = CONFIDENCE_MODEL
    z = (w["intercept"]
         + w["log_snr"] * np.log(np.maximum(m["snr"], 1e-3))
         + w["no_neighbours"] * (~np.isfinite(m["agreement"]))
         + w["flatness"] * m["flatness"]
         + w["width_excess"] * np.where(np.isfinite(excess), excess, _WIDTH_EXCESS_FILL)
         + w["relative_scale"] * m["scale"] / float(max_blur)
         + w["monotonicity"] * m["monotonicity"])
    return 1.0 / (1.0 + np.exp(-z))
