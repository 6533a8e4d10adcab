"""The PSF-field glyphs of the napari overlay: drawn by the engine (:mod:`..core.psf_view`).

Kept so that the widgets (and code written against them) import from here; the drawing
is pure numpy and shared with ``edgecme psf``'s figure.
"""

from ..core.psf_view import BACKGROUND, GLYPH_COLOUR, TILE_ALPHA, PsfGlyphs, psf_glyphs

__all__ = ["BACKGROUND", "GLYPH_COLOUR", "TILE_ALPHA", "PsfGlyphs", "psf_glyphs"]
