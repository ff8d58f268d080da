"""The full film, averaged: the object's slow motion driven by the periodic film force of eqs. (3)-(5).

Sec. 3.2 averages the equation of motion (4) over one excitation period: the slow clearance hbar obeys

    m hbar'' = pi r0^2 p_a delta^2 K(sigma(hbar), delta) - 3 pi mu r0^4 / (2 hbar^3) hbar' - m g,

the levitation force of eq. (12) plus the squeeze-film damping of eq. (6) (eq. 13 in SI). Here K is
not the delta -> 0 calibration of eq. (13) but the periodic steady state of Reynolds' equation itself
at the actual delta = |a| / hbar, solved by harmonic balance (:mod:`nfal.models.harmonic_balance`)
and tabulated once per shape and grid (:class:`~nfal.models.film_force_table.FilmForceTable`). The
film is quasi-steady within a slow step: its slowest mode decays by exp(-2 pi 5.78 / sigma) per
period, against slow motion over hundreds of periods (Sec. 3.2, "the time constants of the pressure
are considerably lower").

Built with the rig (``FilmForceTable(..., rig=rig)``), the table includes the object's own fast
oscillation chi (first order in delta) in the gap, and so its effect on the mean force (2.2e-4 of the
clearance for case a of Table 1, 2e-3 for a piston; docs/film_solvers.md). What it leaves out against
:class:`~nfal.models.coupled.CoupledModel` (time marching, the reference): chi beyond first order, and
the film's delay in following slow motion beyond eq. (6). Touchdown and lift-off are those of
:class:`~nfal.models.plant.SimplifiedPlant`.
"""

from __future__ import annotations


import numpy as np

from . import slow_kernels
from .calibration import CalibrationFunction
from .film_force_table import FilmForceTable
from .plant import DEFAULT_REST_GAP, SimplifiedPlant
from .rig import RigParameters


class AveragedFilmPlant(SimplifiedPlant):
    """Eq. (13) with K(sigma, delta) of the full film at finite delta (harmonic balance), in SI.

    Parameters
    ----------
    rig : RigParameters
    table : FilmForceTable
        The periodic film force of the excitation form.
    rest_gap : float
        Closest approach to the driving surface [m].
    """

    def __init__(self, rig: RigParameters, table: FilmForceTable, rest_gap: float = DEFAULT_REST_GAP) -> None:
        super().__init__(rig, _DeltaZeroView(table), rest_gap)
        self.table = table
        # |zeta / delta| at the table's squeeze numbers, for oscillation()
        self._log_sigmas = np.log(table.sigmas)
        self._response = np.abs([table.response(sigma) for sigma in table.sigmas])
        # numba loads (or compiles) the table's kernel at its first call, ~0.5 s: here, not in a real-time step
        # (it cost 3 ms in the lift-off tick of the emulated rig when left lazy)
        table.scalar(float(rig.squeeze_number(rig.reference_clearance)), 0.0)

    def levitation_force(self, height, excitation):
        """Period-averaged film force pi r0^2 p_a delta^2 K(sigma, delta) [N] (eq. 12) at finite delta."""
        height = np.asarray(height, dtype=float)
        delta = np.asarray(excitation, dtype=float) / height
        return self.rig.film_force_scale * delta**2 * self.table(self.rig.squeeze_number(height), delta)

    def oscillation_table(self) -> tuple[float, np.ndarray, np.ndarray]:
        """What :meth:`oscillation` interpolates: sigma h^2, log sigma at the table's points, |zeta / delta| there."""
        return self._sigma_scale, self._log_sigmas, self._response

    def oscillation(self, height: float, excitation: float) -> float:
        """Amplitude chi [m] of the object's fast oscillation (eq. 1), to first order in delta:
        |zeta| hbar = |a| |zeta / delta| (:meth:`FilmForceTable.response`, interpolated linearly in log sigma
        between the table's points; 0 for a table without a rig)."""
        return float(slow_kernels.oscillation(self._sigma_scale, self._log_sigmas, self._response, height, excitation))


class _DeltaZeroView(CalibrationFunction):
    """K(sigma, delta -> smallest tabulated delta) of a table: the calibration SimplifiedPlant keeps for
    its eq.-(13) helpers (the forces use the table at the actual delta)."""

    def __init__(self, table: FilmForceTable) -> None:
        super().__init__(table.sigma_range, "harmonic balance")
        self._table = table

    def _value(self, sigma):
        return self._table(sigma, 0.0)

    def _slope(self, sigma):
        step = 1e-6 * sigma
        return (self._table(sigma + step, 0.0) - self._table(sigma - step, 0.0)) / (2.0 * step)
