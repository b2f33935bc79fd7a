"""Which physical effect is the model missing (docs/diagnosis.md): `diagnose` one step,
`discover` step after step, `unexplained` what remains."""

from torchcal.diagnosis.candidates import Candidate
from torchcal.diagnosis.crossval import RefitCV, fold_ids, refit_cv
from torchcal.diagnosis.diagnose import Diagnosis, Discovery, diagnose, discover, where_it_fails
from torchcal.diagnosis.selection import ALPHA, MIN_GAIN, REFITS
from torchcal.diagnosis.step import Scored, Step, score_step
from torchcal.diagnosis.unexplained import Unexplained, unexplained
from torchcal.diagnosis.variance import fit_variances

__all__ = ["ALPHA", "MIN_GAIN", "REFITS", "Candidate", "Diagnosis", "Discovery", "RefitCV", "Scored", "Step",
           "Unexplained", "diagnose", "discover", "fit_variances", "fold_ids", "refit_cv", "score_step",
           "unexplained", "where_it_fails"]
