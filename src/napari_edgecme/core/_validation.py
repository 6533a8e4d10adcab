"""Input validation, the float policy and the ``rng`` policy, in one place.

Every public function of the engine funnels its inputs through these helpers, so
that bad input fails early with one ``ValueError`` that names the parameter, what
was expected and what came -- never with an exception from deep inside numpy.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = [
    "FLOAT_RANGE",
    "as_float_image",
    "as_rng",
    "check_bool",
    "check_choice",
    "check_positive",
    "float_dtype",
]


#: Floating-point images outside this range are refused as not scaled to [0, 1].
FLOAT_RANGE = (-0.5, 1.5)


def float_dtype(dtype) -> np.dtype:
    """Return the floating dtype the engine computes in for input ``dtype``.

    float32 and float64 are kept; every other dtype (bool, integers, float16)
    computes in float32. This is the single float policy of the engine.
    """
    dtype = np.dtype(dtype)
    if dtype == np.float64:
        return np.dtype(np.float64)
    return np.dtype(np.float32)


def as_float_image(image, name: str = "image", *, allow_rgb: bool = False,
                   min_size: int = 2, check_range: bool = True) -> np.ndarray:
    """Validate an image and return it as floating point in [0, 1] (a new array).

    Parameters
    ----------
    image : array_like of shape (M, N) or (M, N, 3)
        Gray or (when ``allow_rgb``) RGB image. Integer images are scaled by the
        maximum of their dtype (uint8 by 255, uint16 by 65535, ...); bool maps to
        {0, 1}; floating images are taken as they are and must lie in [0, 1] (values
        within :data:`FLOAT_RANGE` are tolerated: noise and ringing overshoot).
    name : str
        Parameter name used in error messages.
    allow_rgb : bool
        Accept a trailing channel axis of length 3 (RGB).
    min_size : int
        Smallest accepted number of rows and of columns.
    check_range : bool
        Refuse floating images outside [0, 1] (the rule for a user's input). The
        engine passes ``False`` for its own intermediate images -- contrast-stretched
        pyramid levels, latent estimates -- whose range is not the file's, to
        functions whose result does not depend on the [0, 1] scale (gradients,
        linear operators): an internal image must never be refused as bad input.

    Returns
    -------
    ndarray of float32 or float64
        float64 input stays float64, everything else becomes float32.

    Raises
    ------
    ValueError
        On a wrong number of dimensions, too small a size, or non-finite values.
    """
    arr = np.asarray(image)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                   or arr.dtype == np.bool_):
        raise ValueError(f"{name} must be a numeric array; got dtype {arr.dtype}")
    if np.iscomplexobj(arr):
        raise ValueError(f"{name} must be real-valued; got dtype {arr.dtype}")
    expected = "(rows, cols) or (rows, cols, 3)" if allow_rgb else "(rows, cols)"
    ok_ndim = arr.ndim == 2 or (allow_rgb and arr.ndim == 3 and arr.shape[2] == 3)
    if not ok_ndim:
        raise ValueError(f"{name} must have shape {expected}; got shape {arr.shape}"
                         f"{_shape_hint(arr.shape, allow_rgb, name)}")
    if arr.shape[0] < min_size or arr.shape[1] < min_size:
        raise ValueError(
            f"{name} must be at least {min_size}x{min_size} pixels; got "
            f"{arr.shape[0]}x{arr.shape[1]}"
        )
    dtype = float_dtype(arr.dtype)
    if arr.dtype == np.bool_:
        out = arr.astype(dtype)
    elif np.issubdtype(arr.dtype, np.integer):
        info = np.iinfo(arr.dtype)
        out = arr.astype(dtype)
        if info.min < 0:
            out = np.clip(out, 0, None)
        out /= dtype.type(info.max)
    else:
        out = arr.astype(dtype, copy=True)
        if not np.all(np.isfinite(out)):
            bad = int(np.count_nonzero(~np.isfinite(out)))
            raise ValueError(f"{name} contains {bad} non-finite values (NaN or inf)")
        lo, hi = float(out.min()), float(out.max())
        if check_range and (lo < FLOAT_RANGE[0] or hi > FLOAT_RANGE[1]):
            raise ValueError(
                f"{name} must be scaled to [0, 1] for floating-point input; got values in "
                f"[{lo:g}, {hi:g}] (divide 8-bit data by 255, 16-bit data by 65535)"
            )
    return out


def _shape_hint(shape, allow_rgb: bool, name: str) -> str:
    """What to do about an image of a refused ``shape``, as a parenthesised suffix."""
    if len(shape) == 3 and shape[2] == 1:
        return f" (one channel: pass {name}[..., 0])"
    if len(shape) == 3 and shape[2] in (2, 4):
        kind = "gray+alpha" if shape[2] == 2 else "RGBA"
        keep = "[..., 0]" if shape[2] == 2 or not allow_rgb else "[..., :3]"
        return f" ({kind}: drop the alpha channel, {name}{keep})"
    if len(shape) == 3 and shape[2] == 3 and not allow_rgb:
        return " (RGB: convert to gray first)"
    if len(shape) >= 3:
        return " (a stack or volume: pass one 2-D plane at a time)"
    return ""


def as_rng(rng) -> np.random.Generator:
    """Turn anything :func:`numpy.random.default_rng` accepts into a Generator."""
    if isinstance(rng, np.random.Generator):
        return rng
    try:
        return np.random.default_rng(rng)
    except (TypeError, ValueError) as err:
        raise ValueError(f"rng must be None, an int seed or a numpy Generator; "
                         f"got {rng!r}") from err


def check_choice(value, name: str, choices) -> str:
    """Return ``value`` if it is one of ``choices``, else raise a ValueError naming them."""
    if not isinstance(value, str) or value not in choices:
        listed = ", ".join(repr(c) for c in choices)
        raise ValueError(f"{name} must be one of {listed}; got {value!r}")
    return value


def check_bool(value, name: str) -> bool:
    """Return ``value`` as a bool if it is one (Python or numpy), else a ValueError."""
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def check_positive(value, name: str, *, integer: bool = False, allow_zero: bool = False,
                   maximum=None):
    """Return ``value`` if it is a finite positive number (an int when ``integer``)."""
    kind = "integer" if integer else "number"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a positive {kind}; got {value!r}")
    if integer and not float(value).is_integer():
        raise ValueError(f"{name} must be a positive integer; got {value!r}")
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite {kind} {bound}; got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be <= {maximum}; got {value!r}")
    return int(value) if integer else float(value)


def first_line(err: BaseException) -> str:
    """The first line of an exception's message (its type's name when it has none).

    Every face of the program reports an error in one line: the CLI, the widgets'
    notifications and status lines, the batch report, the files' "cannot read" messages.
    """
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
