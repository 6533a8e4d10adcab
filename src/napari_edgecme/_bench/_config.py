"""What ``edgecme bench`` measures: the synthetic quality cases and the speed rows."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from .._report import METHOD_NAMES

__all__ = ["BenchConfig", "CaseSpec", "config_dict", "make_config", "quality_cases"]

#: Estimators, by engine name, with their display names.
METHODS = METHOD_NAMES
#: The estimators are told ``max_blur`` = this factor times the true blur extent.
MAX_BLUR_FACTOR = 1.3
NOISE = 0.01
BITS = 8
#: Blur extents of the full quality set (pixels), assigned in turn to the cases.
EXTENTS = (13.0, 19.0, 25.0, 31.0)
#: Speed case: blur extent (px) and ``max_blur`` of the 800x800 estimation.
SPEED_BLUR = 31.0
#: The 12-megapixel RGB case, (rows, cols).
LARGE_SHAPE = (3000, 4000)


@dataclass(frozen=True)
class CaseSpec:
    """One synthetic quality case."""

    name: str
    image: str
    model: str
    extent: float
    seed: int


@dataclass
class BenchConfig:
    """What a benchmark run measures (see :func:`make_config`)."""

    quick: bool
    size: int
    cases: list[CaseSpec]
    speed_size: int
    speed_methods: tuple[str, ...]
    deconv_methods: tuple[str, ...]
    repeat: int  # fresh-process runs per speed row (median reported)
    operator_repeat: int  # operator applications per timing (median reported)
    large: bool
    timeout: float  # seconds per run
    n_iter: int | None = None
    noise: float = NOISE
    bits: int = BITS
    extra: dict = field(default_factory=dict)


def quality_cases(images, models, extents, seed: int = 0) -> list[CaseSpec]:
    """Every image x model, the extents assigned in turn; case ``i`` is seeded ``seed + i``."""
    cases = []
    for i, (image, model) in enumerate((im, m) for im in images for m in models):
        extent = extents[i % len(extents)]
        cases.append(CaseSpec(f"{image}-{model}-{extent:g}px", image, model, float(extent),
                              seed + i))
    return cases


def make_config(quick: bool = False, size: int | None = None, cases: int | None = None,
                speed_size: int | None = None, repeat: int | None = None,
                large: bool = True, n_iter: int | None = None) -> BenchConfig:
    """The full or ``quick`` benchmark, with optional overrides (the test suite shrinks it).

    Full: 8 cases (camera, astronaut, coffee, edges x inplane, rotation; extents 13, 19,
    25, 31 px in turn) at 512 px; speed rows repeated 3 times; the 12 MP case.
    Quick: 4 cases (camera, edges x inplane, rotation; 13 and 15 px) at 320 px; speed
    rows once, EpAlone and Xu+Ep only, hyper-Laplacian only, no 12 MP case.

    The sizes follow from the edge profiles: EpAlone needs at least 12 of them, and a
    blur of 25-31 px leaves that many in a photo only from about 512 px up (at 256 px a
    19 px blur already leaves fewer than 12 in most of the photos).
    """
    if quick:
        specs = quality_cases(("camera", "edges"), ("inplane", "rotation"), (13.0, 15.0))
        config = BenchConfig(True, 320, specs, 800, ("ep", "xu+ep"), ("hyperlaplacian",),
                             1, 5, False, 900.0)
    else:
        specs = quality_cases(("camera", "astronaut", "coffee", "edges"),
                              ("inplane", "rotation"), EXTENTS)
        config = BenchConfig(False, 512, specs, 800, tuple(METHODS),
                             ("hyperlaplacian", "rl", "wiener"), 3, 9, large, 1800.0)
    if size is not None:
        config.size = int(size)
    if cases is not None:
        config.cases = config.cases[:int(cases)]
    if speed_size is not None:
        config.speed_size = int(speed_size)
    if repeat is not None:
        config.repeat = config.operator_repeat = int(repeat)
    if not large:
        config.large = False
    config.n_iter = n_iter
    return config


def config_dict(config: BenchConfig) -> dict:
    d = asdict(config)
    d["cases"] = [c["name"] for c in d["cases"]]
    return d
