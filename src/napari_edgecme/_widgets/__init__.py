"""napari dock widgets of napari-edgecme (the only place, with ``_sample_data``, that imports Qt).

One module per widget -- :mod:`.edge_profiles`, :mod:`.camera_motion`,
:mod:`.deconvolution` -- and the plumbing they share, one module per job:
:mod:`._runner` (engine runs in a worker thread, throttled progress, Run/Cancel),
:mod:`._layers` (layer metadata, choices and transforms), :mod:`._dock` (dock layout and
tab joining), :mod:`._max_blur` (the "max blur" control), :mod:`._plots` (themed
canvases) and :mod:`._psf_view` (the PSF-field overlay, drawn by the engine). napari
finds the widgets through ``napari.yaml``.
"""
