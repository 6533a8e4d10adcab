"""The ``edgecme`` command line: blind deblurring from the shell.

::

    edgecme demo                                   # the whole pipeline on a bundled photo
    edgecme deblur photo.png -o sharp.png          # estimate the camera motion, deconvolve
    edgecme batch shoot/ -o restored/              # many photos on a local Dask cluster
    edgecme estimate photo.png -o motion.json      # only the motion
    edgecme deconvolve photo.png --motion motion.json -o sharp.png
    edgecme profiles photo.png -o profiles.json --plot profiles.png
    edgecme psf motion.json -o psf-field.png --grid 5x5
    edgecme synth sharp.png -o blurred.png --save-motion truth.json
    edgecme bench --quick

Conventions
-----------
* Images are read and written by extension (:mod:`napari_edgecme.core.io`): PNG 8/16 bit,
  TIFF (float32 kept), JPEG, BMP. The output depth follows the input (a 16-bit photo
  gives a 16-bit PNG). RGB is estimated on luminance and deconvolved per channel; the
  alpha channel of gray+alpha or RGBA input is dropped (with a warning unless it is
  opaque); stacks and volumes are refused.
* Outputs are written only when everything has been computed, each to a temporary
  name in the target folder and renamed into place: a failed or interrupted run leaves
  no output file, and never a half-written one.
* Progress: a one-line bar on stderr while a long step runs. It is drawn only when
  stderr is a terminal (so logs, pipes and CI output stay clean) and ``--quiet``
  silences it. Engine warnings appear as ``edgecme: warning: ...`` lines; a successful
  run ends with a one-line summary on stderr (not with ``--quiet``). Nothing is
  written to stdout except ``--help`` and ``--version``.
* Exit status: 0 success; 2 bad input or usage (one line ``edgecme: error: ...`` on
  stderr, nothing written); 1 an internal error, i.e. a bug (one line; ``--debug``
  shows the traceback); 130 interrupted (Ctrl-C). ``batch`` exits with 1 also when some
  photos failed (each is reported; the others are written).
* Randomness: ``--seed`` (default 0) seeds every random choice, so the same input,
  options and seed give identical output files.

The command never imports Qt or napari.

Layout: :mod:`._console` (messages, progress bar, exit statuses), :mod:`._files` (input and
output checks), :mod:`._options` (options to engine parameters), the commands by theme
(:mod:`._deblur`: estimate, deblur, batch, deconvolve; :mod:`._tools`: profiles, psf,
synth; :mod:`._demo_bench`: demo, bench), :mod:`._parser` and :mod:`._main`.
"""

from __future__ import annotations

from ._console import CLIError, ProgressBar
from ._console import _Console as _Console  # tests patch cli._Console
from ._main import main
from ._parser import build_parser

__all__ = ["CLIError", "ProgressBar", "build_parser", "main"]
