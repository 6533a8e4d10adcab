"""``edgecme`` itself: parse the arguments, run the command, turn failures into exit statuses."""

from __future__ import annotations

import traceback
import warnings

from ..core._validation import first_line
from ._console import (
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    CLIError,
    _Console,
    _UsageError,
    oserror_message,
)
from ._parser import build_parser


def main(argv=None) -> int:
    """Run ``edgecme`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    console = _Console(quiet=False)
    try:
        args = parser.parse_args(argv)
    except _UsageError as err:
        console.error(str(err))
        return EXIT_USAGE
    except SystemExit as done:  # --help, --version
        return done.code if isinstance(done.code, int) else EXIT_OK
    if args.command is None:
        console.error("missing COMMAND (one of demo, deblur, batch, estimate, deconvolve, "
                      "profiles, psf, synth, bench); see 'edgecme --help'")
        return EXIT_USAGE
    console = _Console(quiet=args.quiet)
    try:
        with warnings.catch_warnings():
            # the engine's warnings (e.g. "too few edge profiles, falling back to xu") are
            # for the user: show each once, as one line; other categories keep the
            # interpreter's filters
            warnings.filterwarnings("default", category=UserWarning)
            warnings.showwarning = console.showwarning
            return args.func(args, console)
    except KeyboardInterrupt:
        console.error("interrupted; no output written")
        return EXIT_INTERRUPTED
    except (CLIError, ValueError) as err:
        if args.debug:
            traceback.print_exc()
        console.error(first_line(err))
        return EXIT_USAGE
    except MemoryError:
        if args.debug:
            traceback.print_exc()
        console.error("out of memory; try a smaller image, or --max-side for the estimation")
        return EXIT_USAGE
    except OSError as err:
        if args.debug:
            traceback.print_exc()
        console.error(oserror_message(err))
        return EXIT_USAGE
    except Exception as err:
        if args.debug:
            traceback.print_exc()
        console.error(f"internal error: {type(err).__name__}: {first_line(err)} "
                      "(please report it; --debug shows the traceback)")
        return EXIT_INTERNAL
