"""The showcase commands: demo (the whole pipeline on a bundled photo) and bench."""

from __future__ import annotations

from ._console import EXIT_OK, _Console, _UsageError


def cmd_demo(args, console: _Console) -> int:
    from .. import _demo

    result = _demo.run_demo(args.out, size=args.size, seed=args.seed, n_iter=args.n_iter,
                            log=console.info, warn=console.warn, run=console.run,
                            debug=args.debug)
    console.info(f"wrote {len(result.files)} files to {result.out} in {result.seconds:.0f} s; "
                 f"read {result.report}")
    return EXIT_OK


def cmd_bench(args, console: _Console) -> int:
    from .. import _bench

    if args.suite != "synthetic":
        from .. import _suites

        written = _suites.run_suite(args.suite, args.out, data=args.data, quick=args.quick,
                                    jobs=args.jobs, cases=args.cases, log=console.info)
        console.info("wrote " + ", ".join(str(p) for p in written))
        return EXIT_OK
    if args.data is not None:
        raise _UsageError("--data applies to the lai, levin and real suites "
                          "(see 'edgecme bench --help')")
    written = _bench.run_bench(args.out, quick=args.quick, size=args.size, cases=args.cases,
                               speed_size=args.speed_size, repeat=args.repeat,
                               large=not args.no_large, log=console.info)
    console.info("wrote " + ", ".join(str(p) for p in written))
    return EXIT_OK
