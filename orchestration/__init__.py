"""Runs SSP system structures of anyone's FMI 2.0 co-simulation FMUs over fmpy (never imports nfal.fmus)."""
