"""The headless engine of napari-edgecme (numpy, scipy and scikit-image only; no Qt, no napari)."""
