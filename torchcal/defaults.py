"""The fit's default uncertainties and plausible scales: plain numbers without torch, so
that the command line's option help (which prints them) is built without importing torch.
`torchcal.calibration.fit` and `torchcal.calibration.plausibility` use them from here."""

SIGMA_MM = 0.01   # default position uncertainty of one measurement (laser tracker), mm
SIGMA_DEG = 0.01  # default orientation uncertainty (36 arcsec, tracker 6-D probe), deg
MAX_LENGTH_MM = 5.0  # plausible scale of the MD-H length deviations dd, da, mm
MAX_ANGLE_DEG = 1.0  # plausible scale of the MD-H angle deviations dtheta, dalpha, dbeta, deg
