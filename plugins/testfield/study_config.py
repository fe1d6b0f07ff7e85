"""What the two studies on the simulated test field hold: one configuration.

:class:`StudyConfig` is what both studies simulate and how they select additional parameters;
each study adds its own part — :class:`ControlStudyConfig` (control cases, AP model, Tables 2–4)
and :class:`~.method_study.MethodStudyConfig` (one case, the methods compared, Tables 4 and 5).
"""

from __future__ import annotations

from dataclasses import dataclass

from baarda.pipeline.synthetic.testfield import CASES, TestFieldConfig

__all__ = ["StudyConfig", "ControlStudyConfig"]


@dataclass(frozen=True)
class StudyConfig:
    """The realisations and the simulated errors, and the AP selection's thresholds."""

    repetitions: int = 20
    sigma_image_um: float = 40.0
    sigma_control_mm: float = 0.05
    with_ap_errors: bool = True
    systematic_scale: float = 1.0
    rho_max: float = 0.75
    ap_alpha: float = 0.05

    def field(self, case: int, block: str = "block", ap_model: str = "none",
              calibrate_iop: bool = False) -> TestFieldConfig:
        """The simulator's configuration of one adjusted variant."""
        return TestFieldConfig(case=case, block=block, with_ap_errors=self.with_ap_errors,
                               sigma_image_um=self.sigma_image_um, sigma_control_mm=self.sigma_control_mm,
                               ap_model=ap_model, calibrate_iop=calibrate_iop,
                               systematic_scale=self.systematic_scale)


@dataclass(frozen=True)
class ControlStudyConfig(StudyConfig):
    """The control study's part: which cases, which AP model, how it is selected (Tables 2–4)."""

    ap_model: str = "ebner12"
    calibrate_iop: bool = False
    ap_selection: str = "bundle"
    cases: tuple = CASES
    single_model_case: int | None = 5
