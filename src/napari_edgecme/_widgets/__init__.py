"""napari dock widgets of napari-edgecme (the only place, with ``_sample_data``, that imports Qt).

One module per widget -- :mod:`.edge_profiles`, :mod:`.camera_motion`,
:mod:`.deconvolution` -- and :mod:`._common`, the worker/progress/notification
plumbing they share. napari finds them through ``napari.yaml``.
"""
