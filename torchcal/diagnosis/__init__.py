"""Which physical effect is the model missing (docs/diagnosis.md): `diagnose` one step,
`discover` step after step, `unexplained` what remains.
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.diagnosis.candidates": ["Candidate"],
    "torchcal.diagnosis.crossval": ["RefitCV", "refit_cv"],
    "torchcal.diagnosis.diagnose": ["Diagnosis", "Discovery", "diagnose", "discover", "where_it_fails"],
    "torchcal.diagnosis.selection": ["ALPHA", "MIN_GAIN", "REFITS"],
    "torchcal.diagnosis.step": ["Scored", "Step", "score_step"],
    "torchcal.diagnosis.unexplained": ["Unexplained", "unexplained"],
    "torchcal.diagnosis.variance": ["fit_variances"],
})
