"""The photos of a batch: files, folders and glob patterns, and where each one's outputs go."""

from __future__ import annotations

import glob
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ..core import io as _io

__all__ = ["THUMBS", "Photo", "collect_photos"]

#: Sub-folder of the output folder holding the thumbnails.
THUMBS = "thumbs"
_GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Photo:
    """One input photo: its file and the name of its outputs inside the output folder."""

    source: Path
    name: str

    def outputs(self, out_dir: Path) -> dict[str, Path]:
        """The files a finished photo has in ``out_dir``, by role."""
        thumbs = out_dir / THUMBS
        return {"output": out_dir / self.name,
                "motion": out_dir / f"{self.name}.motion.json",
                "before": thumbs / f"{self.name}.before.png",
                "after": thumbs / f"{self.name}.after.png",
                "psf": thumbs / f"{self.name}.psf.png"}

    def complete(self, out_dir: Path) -> bool:
        """True when the restored image and the motion file (written last) both exist."""
        files = self.outputs(out_dir)
        return files["output"].is_file() and files["motion"].is_file()


def _is_image(path: Path) -> bool:
    return path.suffix.lower() in _io.IMAGE_SUFFIXES and not path.name.startswith(".")


def collect_photos(inputs: Iterable, out_dir=None, recursive: bool = False) -> list[Photo]:
    """The photos named by files, folders and glob patterns, in the order given.

    Parameters
    ----------
    inputs : iterable of str or path-like
        Files (taken whatever their extension), folders (their image files:
        ``.png .tif .tiff .jpg .jpeg .bmp``, hidden files excluded) and glob patterns
        (``*``, ``?``, ``[...]``; ``**`` with ``recursive``).
    out_dir : path-like, optional
        The output folder: files inside it are never inputs, and outputs may not
        overwrite an input.
    recursive : bool
        Also the image files of sub-folders; their outputs mirror the sub-folders.

    Returns
    -------
    list of Photo
        Each file once; the name of a folder's photo is its path relative to the folder,
        any other photo's its file name.

    Raises
    ------
    ValueError
        One line: an input that does not exist, matches nothing or holds no images, two
        photos whose outputs would have the same name, or an output that would overwrite
        an input.
    """
    out = Path(out_dir).resolve() if out_dir is not None else None

    def outside(path: Path) -> bool:
        return out is None or not path.resolve().is_relative_to(out)

    found: list[Photo] = []
    for item in inputs:
        text = os.fspath(item)
        path = Path(text)
        if path.is_dir():
            if out is not None and path.resolve().is_relative_to(out):
                raise ValueError(f"the output folder {out_dir} would overwrite the input "
                                 f"folder {path}; choose an output folder outside it")
            pattern = "**/*" if recursive else "*"
            files = sorted(p for p in path.glob(pattern) if p.is_file() and _is_image(p)
                           and outside(p))
            if not files:
                raise ValueError(f"no image files ({', '.join(_io.IMAGE_SUFFIXES)}) in "
                                 f"folder {path}" + ("" if recursive else " (-r for sub-folders)"))
            found += [Photo(p, p.relative_to(path).as_posix()) for p in files]
        elif path.is_file():
            found.append(Photo(path, path.name))
        elif _GLOB_CHARS & set(text):
            matches = sorted(Path(p) for p in glob.glob(text, recursive=recursive))
            files = [p for p in matches if p.is_file() and _is_image(p) and outside(p)]
            if not files:
                raise ValueError(f"no image files match {text}")
            found += [Photo(p, p.name) for p in files]
        else:
            raise ValueError(f"input not found: {text}")
    photos: list[Photo] = []
    seen_sources: set[Path] = set()
    by_name: dict[str, Photo] = {}
    for photo in found:
        key = photo.source.resolve()
        if key in seen_sources:
            continue
        seen_sources.add(key)
        other = by_name.get(photo.name)
        if other is not None:
            raise ValueError(f"{other.source} and {photo.source} would both be written as "
                             f"{photo.name}; run them as separate batches")
        by_name[photo.name] = photo
        if out is not None and any(p.resolve() == key
                                   for p in photo.outputs(out).values()):
            raise ValueError(f"the output folder {out_dir} would overwrite the input "
                             f"{photo.source}; choose another output folder")
        photos.append(photo)
    return photos
