"""What the two studies on the simulated test field hold: one configuration.

:class:`StudyConfig` is what both studies simulate and how they select additional parameters —
the simulated errors are the simulator's own declaration
(:class:`~baarda.pipeline.synthetic.testfield.SimulatedErrors`: ``sigma_image_um`` and its
default are declared once, there); each study adds its own part — :class:`ControlStudyConfig`
(control cases, AP model, Tables 2–4; also the ``testfield-control-study`` stage's option table)
and :class:`~.method_study.MethodStudyConfig` (one case, the methods compared, Tables 4 and 5).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

from baarda.pipeline.api import option
from baarda.pipeline.options import check_bounds
from baarda.pipeline.synthetic.testfield import CASES, SimulatedErrors, TestFieldConfig

__all__ = ["StudyRuns", "StudyConfig", "ControlStudyConfig"]


@dataclass(frozen=True, kw_only=True)
class StudyRuns:
    """How many realisations, and the AP selection's thresholds: declared once for both studies'
    configurations and the method study's options (bounds checked on construction)."""

    repetitions: int = option(20, "number of simulated realisations (the same noise for every variant); the "
                                  "tables give the RMS over them")
    rho_max: float = option(0.75, "AP selection: remove parameters correlated above this, one after another "
                                  "(the paper's 0.75)", gt=0, lt=1)
    ap_alpha: float = option(0.05, "then remove parameters not significant at this level (t-test), one after "
                                   "another; 0 keeps every parameter that passed the correlation rule", ge=0, lt=1)

    def __post_init__(self):
        check_bounds(self)


@dataclass(frozen=True)
class StudyConfig(SimulatedErrors, StudyRuns):
    """The realisations and the simulated errors, and the AP selection's thresholds."""

    def field(self, case: int, block: str = "block", ap_model: str = "none",
              calibrate_iop: bool = False) -> TestFieldConfig:
        """The simulator's configuration of one adjusted variant."""
        errors = {f.name: getattr(self, f.name) for f in fields(SimulatedErrors)}     # what both declare once
        return TestFieldConfig(case=case, block=block, ap_model=ap_model, calibrate_iop=calibrate_iop, **errors)


@dataclass(frozen=True)
class ControlStudyConfig(StudyConfig):
    """The control study's part: which cases, which AP model, how it is selected (Tables 2–4).

    Also the ``testfield-control-study`` stage's option table (one definition); ``cases`` is
    kept sorted, each case once."""

    repetitions: int = option(10, "number of simulated realisations (the same noise for every case and "
                                  "with/without APs); the tables give the RMS over them")
    seed: int | None = option(None, "seed of the simulations; default: the project's seed for this stage")
    ap_model: Literal["ebner12", "brown"] = option(
        "ebner12", "AP model of the self-calibrating runs ('ebner12' as the paper, or 'brown')")
    calibrate_iop: bool = option(False, "with APs, c, xp, yp (the paper's dc, dxp, dyp) are free too (the "
                                        "bundle's selection keeps them; the study's treats them as candidates)")
    ap_selection: Literal["bundle", "study"] = option(
        "bundle", "AP selection: the bundle's (pipeline/adjustment/apselect.py; the study's own when the block is "
                  "singular with every AP free) or always the study's (correlations with the orientations too)")
    cases: tuple[int, ...] = option(CASES, "control cases to run")
    single_model: bool = option(True, "also adjust the single model at 4.0 m (Table 4)")
    single_model_case: int = option(5, "control case of the single-model comparison (the paper: 5)")

    def __post_init__(self):
        super().__post_init__()
        bad = [c for c in self.cases if c not in CASES]
        if bad or not self.cases:
            raise ValueError(f"cases must be a non-empty list drawn from {list(CASES)}, got {list(self.cases)}")
        if self.single_model_case not in CASES:
            raise ValueError(f"single_model_case must be one of {list(CASES)}")
        if self.ap_model not in ("ebner12", "brown"):
            raise ValueError("ap_model must be 'ebner12' or 'brown'")
        object.__setattr__(self, "cases", tuple(sorted(set(self.cases))))
