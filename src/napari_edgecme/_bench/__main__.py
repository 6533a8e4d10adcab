"""``python -m napari_edgecme._bench``: a fresh-process job (as ``napari_edgecme._worker``)."""

from .._worker import worker_main

worker_main()
