"""The files of a command: reading the input image, checking and writing the outputs."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from ..core import io as _io
from ._console import CLIError, _Console


def read_input_image(path, console: _Console | None = None) -> np.ndarray:
    """Read an image file as (H, W) or (H, W, 3); alpha is dropped, stacks refused."""
    path = Path(path)
    arr = _io.read_image(path)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    elif arr.ndim == 3 and arr.shape[2] in (2, 4):
        alpha = arr[..., -1]
        opaque = np.iinfo(alpha.dtype).max if np.issubdtype(alpha.dtype, np.integer) else 1
        if console is not None and np.any(alpha != opaque):
            console.warn(f"{path}: the alpha channel is ignored")
        arr = arr[..., 0] if arr.shape[2] == 2 else arr[..., :3]
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise CLIError(f"{path}: expected a gray or RGB image, shape (rows, cols) or "
                       f"(rows, cols, 3); got shape {arr.shape} (a stack or volume: "
                       "save its planes as separate images)")
    return arr


def output_bits(image: np.ndarray) -> int | None:
    """PNG depth for an output made from ``image``: 16 for 16-bit input, else the default."""
    return 16 if image.dtype in (np.uint16, np.int32, np.uint32, np.int64, np.uint64) else None


def _existing_input(path: Path, what: str) -> Path:
    if not path.exists():
        raise CLIError(f"{what} not found: {path}")
    if path.is_dir():
        raise CLIError(f"expected a file for the {what}, got a directory: {path}")
    return path


def _check_output(path: Path, option: str, image: bool = False) -> Path:
    """Fail early (before any work) if ``path`` cannot be written."""
    if path.is_dir():
        raise CLIError(f"{option} {path} is a directory; give a file name")
    folder = path.parent
    if not folder.is_dir():
        raise CLIError(f"output folder does not exist: {folder} (for {option} {path})")
    if not os.access(folder, os.W_OK):
        raise CLIError(f"output folder is not writable: {folder} (for {option} {path})")
    if image and path.suffix.lower() not in _io.IMAGE_SUFFIXES:
        suffix = repr(path.suffix) if path.suffix else "(no extension)"
        raise CLIError(f"cannot write {option} {path}: unsupported image format {suffix}; "
                       "use one of " + ", ".join(_io.IMAGE_SUFFIXES))
    return path


def _distinct(inputs, outputs) -> None:
    """Refuse outputs that overwrite an input or each other."""
    seen: dict[Path, str] = {}
    for option, path in inputs:
        seen[path.resolve()] = option
    for option, path in outputs:
        key = path.resolve()
        if key in seen:
            raise CLIError(f"{option} {path} would overwrite {seen[key]}; choose another name")
        seen[key] = option


@contextlib.contextmanager
def _writing(*paths):
    """Temporary paths for several outputs, all renamed into place when the block succeeds."""
    with contextlib.ExitStack() as stack:
        yield [stack.enter_context(_io.atomic_path(p)) for p in paths]
