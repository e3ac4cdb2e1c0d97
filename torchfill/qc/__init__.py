"""Quality control of a fill: a verdict per gap -- ``ok``, ``check`` or ``reject`` -- with its
reasons (``torchfill qc``, ``fill --report``).

:mod:`torchfill.qc.verdicts` judges each gap (pure functions of the input, the fill and its error
estimate; the tests and their constants are described there); :mod:`torchfill.qc.report` gives
the verdicts as text, JSON and a self-contained HTML page.
"""
from .report import (format_table, html_report, summary, thresholds_json, to_json,
                     unfilled_samples)
from .verdicts import (AGREE_MM, BODY_SCALE_MM, DISAGREE_MM, EST_CHECK_MM, EST_REJECT_MM,
                       EST_RELATIVE, EXTRAPOLATED_SECONDS, RIGID_CHECK, RIGID_REJECT, SAME_MM,
                       SHORT_SECONDS, STEP_AT_CAP, STEP_ROUNDING, VERDICTS, Thresholds, alone,
                       drop_rejected, est_rmse, gap_table, per_mm, rigid_partners,
                       sample_verdicts, table_thresholds, thresholds, untested, verdict)

__all__ = ["AGREE_MM", "BODY_SCALE_MM", "DISAGREE_MM", "EST_CHECK_MM", "EST_REJECT_MM",
           "EST_RELATIVE", "EXTRAPOLATED_SECONDS", "RIGID_CHECK", "RIGID_REJECT", "SAME_MM",
           "SHORT_SECONDS",
           "STEP_AT_CAP", "STEP_ROUNDING", "VERDICTS", "Thresholds", "alone", "drop_rejected",
           "est_rmse", "format_table", "gap_table", "html_report", "per_mm", "rigid_partners",
           "sample_verdicts", "summary", "table_thresholds", "thresholds", "thresholds_json", "to_json", "unfilled_samples",
           "untested", "verdict"]
