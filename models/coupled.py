"""The full model: Reynolds' equation (3) with BCs (5) coupled to the object's motion (4).

The gap is h(r, t) = z(t) - |a| eps_hat(R) sin(omega t) (eq. 1, a(r) = |a| eps_hat(R)). With the
reference clearance h0 of :class:`~nfal.models.rig.RigParameters`: Z = z / h0, A = |a| / h0,
T = omega t and H = Z - A eps_hat(R) sin T. Then, with Lambda = sigma Hbar^2 = 12 mu omega r0^2 /
(p_a h0^2) a constant of the rig,

    d/dR (R H^3 P dP/dR) = Lambda R d(P H)/dT,        dP/dR(0) = 0, P(1) = 1       (3), (5)
    Z'' = 2 C_s* int_0^1 R (P - 1) dR - G                                          (4) for z

with C_s*, G of eq. (14). (Eq. 4 is written for H; for z the excitation term drops out.)

Film and object are marched together, fully implicitly: the finite volumes and BDF2 of
:mod:`nfal.models.reynolds` for the film, BDF2 for (Z, Z'), one Newton iteration system per step.
Z' is eliminated through its BDF2 relation, so the unknowns are the gauge pressures u = P - 1 of
the non-rim nodes plus Z: a tridiagonal block bordered by one dense row (the film force on the
object) and one dense column (the gap's dependence on Z). It is solved by block elimination with
two Thomas sweeps sharing one factorisation (the Sherman-Morrison form of the bordered system).

Excitation |a| is held constant over each excitation period and sampled at the period's start,
where sin T = 0, so a change of |a| never makes the gap jump. Output is per excitation period.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Callable

import numba
import numpy as np

from nfal.errors import (ConvergenceError, GapClosedError, InvalidParameterError, require_amplitude, require_finite,
                         require_positive)

from . import numba_cache
from .excitation import ExcitationShape
from .perturbation import radial_grid
from .film_kernel import face_fluxes, flux_jacobian, thomas_factor, thomas_substitute
from .reynolds import SLOWEST_FILM_EIGENVALUE, check_grid, perturbation_film
from .rig import RigParameters

#: The files whose kernels these kernels call (the Thomas solver's): numba's cache of them is keyed by both sources.
KERNEL_DEPENDENCIES = ("film_kernel.py",)

numba_cache.install()  # before the kernels below: their compiled code outlives an FMU's temporary folder

logger = logging.getLogger(__name__)

#: Newton stops when the largest update of P - 1 or Z = z / h0 is below this; convergence is quadratic
#: (exact Jacobian), so what is left after that update is of order its square, ~1e-18.
NEWTON_TOLERANCE = 1e-9
NEWTON_MAX_ITERATIONS = 30
#: How many chunks a simulation is cut into for ``progress`` reports.
PROGRESS_CHUNKS = 100
#: Envelope following: full periods per burst, and the longest jump (periods).
ENVELOPE_BURST = 30
ENVELOPE_MAX_JUMP = 5000
#: Relative per-period change of the slow height below which it is treated as noise (rate not measured).
ENVELOPE_NOISE = 1e-10


def _projective_limit(mu: float, burst: int) -> float:
    """Largest jump M with mu^(burst-1) |(M + 1) mu - M| <= 1/2 for a mode contracting by mu per period."""
    if mu <= 0.0:
        return math.inf
    return (0.5 / mu ** (burst - 1) + mu) / (1.0 - mu)

Excitation = float | Callable[[float], float]


STATUS_OK, STATUS_NEWTON, STATUS_GAP = 0, 1, 2


@numba.njit(cache=True)
def _march_coupled(state, amplitudes, eps_nodes, eps_faces, conductance, volumes, film_number, stiffness,
                   gravity, steps, out_height, out_velocity, out_cos, out_sin):
    """March len(amplitudes) excitation periods of the coupled film + object with BDF2 + Newton.

    ``state`` = [u (nodes) at T_k, u at T_{k-1}, Z_k, Z_{k-1}, W_k, W_{k-1}] at a period boundary,
    updated in place. ``amplitudes[p]`` is A = |a| / h0 in period p. Per period the means of Z and
    W = Z' and the first-harmonic sums of W go to the ``out_*`` arrays. Returns (status, periods
    done, step of failure).
    """
    nodes = eps_nodes.shape[0]
    m = nodes - 1
    dt = 2.0 * np.pi / steps
    u_now = state[:nodes].copy()
    u_prev = state[nodes:2 * nodes].copy()
    z_now = state[2 * nodes]
    z_prev = state[2 * nodes + 1]
    w_now = state[2 * nodes + 2]
    w_prev = state[2 * nodes + 3]
    lower = np.zeros(m)
    diag = np.empty(m)
    upper = np.empty(m)
    res = np.empty(m)
    column = np.empty(m)
    x = np.empty(m)
    y = np.empty(m)
    work = np.empty(2 * m)
    hist = np.empty(m)
    h_nodes = np.empty(nodes)
    inv_h_faces = np.empty(nodes - 1)
    c_faces = np.empty(nodes)  # c_faces[f] / Lambda; the last entry stays 0 (no face beyond the rim)
    flux = np.empty(nodes)  # flux[f] / Lambda, same layout
    u = np.empty(nodes)
    sines = np.sin(dt * np.arange(-1, steps + 1))  # sines[j + 1] = sin(j dT)
    cosines = np.cos(dt * np.arange(-1, steps + 1))
    mass_rate = volumes / (2.0 * dt)
    inv_film = 1.0 / film_number
    z_gain = 9.0 / (4.0 * dt * dt)
    inv_2dt = 1.0 / (2.0 * dt)
    for p in range(amplitudes.shape[0]):
        amp = amplitudes[p]
        sum_z = 0.0
        sum_w = 0.0
        sum_wc = 0.0
        sum_ws = 0.0
        for j in range(steps):
            s_now = amp * sines[j + 1]
            s_prev = amp * sines[j]
            for n in range(m):
                hist[n] = (-4.0 * (1.0 + u_now[n]) * (z_now - eps_nodes[n] * s_now)
                           + (1.0 + u_prev[n]) * (z_prev - eps_nodes[n] * s_prev))
            z_hist = -4.0 * z_now + z_prev
            w_hist = -4.0 * w_now + w_prev
            s = amp * sines[j + 2]
            for n in range(nodes):
                u[n] = 2.0 * u_now[n] - u_prev[n]
            u[nodes - 1] = 0.0
            z = 2.0 * z_now - z_prev
            converged = False
            for _ in range(NEWTON_MAX_ITERATIONS):
                gap_open = True
                for n in range(nodes):
                    h_nodes[n] = z - eps_nodes[n] * s
                    gap_open = gap_open and h_nodes[n] > 0.0
                for f in range(nodes - 1):
                    hf = z - eps_faces[f] * s
                    gap_open = gap_open and hf > 0.0
                    inv_h_faces[f] = 1.0 / hf
                    c_faces[f] = conductance[f] * hf * hf * hf * inv_film
                if not gap_open:
                    state[2 * nodes] = z
                    return STATUS_GAP, p, j
                face_fluxes(u, c_faces, flux, nodes - 1)
                flux_jacobian(u, c_faces, lower, diag, upper)
                force = 0.0
                flux_below = 0.0
                dflux_below = 0.0
                for n in range(m):
                    one_u = 1.0 + u[n]
                    force += volumes[n] * u[n]
                    dflux = 3.0 * flux[n] * inv_h_faces[n]
                    res[n] = (flux[n] - flux_below) - mass_rate[n] * (3.0 * one_u * h_nodes[n] + hist[n])
                    diag[n] += 3.0 * mass_rate[n] * h_nodes[n]
                    column[n] = 3.0 * mass_rate[n] * one_u - (dflux - dflux_below)
                    flux_below = flux[n]
                    dflux_below = dflux
                w = (3.0 * z + z_hist) * inv_2dt
                res_z = -((3.0 * w + w_hist) * inv_2dt - 2.0 * stiffness * force + gravity)
                thomas_factor(lower, diag, upper, work)  # one factorisation, two right-hand sides
                thomas_substitute(lower, work, res, x)
                thomas_substitute(lower, work, column, y)
                # border row: z_gain dZ - 2 C_s sum V du = res_z, with du = x - y dZ
                row_x = 0.0
                row_y = 0.0
                for n in range(m):
                    row_x += volumes[n] * x[n]
                    row_y += volumes[n] * y[n]
                dz = (res_z + 2.0 * stiffness * row_x) / (z_gain + 2.0 * stiffness * row_y)
                largest = abs(dz)
                for n in range(m):
                    du = x[n] - y[n] * dz
                    u[n] += du
                    largest = max(largest, abs(du))
                z += dz
                if largest <= NEWTON_TOLERANCE:
                    converged = True
                    break
            if not converged:
                return STATUS_NEWTON, p, j
            w = (3.0 * z + z_hist) * inv_2dt
            for n in range(nodes):
                u_prev[n] = u_now[n]
                u_now[n] = u[n]
            z_prev = z_now
            z_now = z
            w_prev = w_now
            w_now = w
            sum_z += z
            sum_w += w
            sum_wc += w * cosines[j + 2]
            sum_ws += w * sines[j + 2]
        out_height[p] = sum_z / steps
        out_velocity[p] = sum_w / steps
        out_cos[p] = sum_wc
        out_sin[p] = sum_ws
        state[:nodes] = u_now
        state[nodes:2 * nodes] = u_prev
        state[2 * nodes] = z_now
        state[2 * nodes + 1] = z_prev
        state[2 * nodes + 2] = w_now
        state[2 * nodes + 3] = w_prev
    return STATUS_OK, amplitudes.shape[0], 0


@dataclasses.dataclass(frozen=True)
class CoupledTrajectory:
    """Per-excitation-period output of :meth:`CoupledModel.simulate` (SI units).

    Attributes
    ----------
    time : ndarray
        Mean time [s] of the samples of each period (its middle).
    height : ndarray
        Period-averaged object position z, the slow clearance hbar of eq. (1) [m].
    velocity : ndarray
        Period-averaged dz/dt, the slow velocity [m/s].
    oscillation : ndarray
        Amplitude of the fast oscillation chi of eq. (1) [m]: the first harmonic of dz/dt over the
        period divided by omega (insensitive to the slow drift of z).
    excitation : ndarray
        |a| [m] applied in each period.
    marched_periods : int
        Periods marched in full (all of them, unless envelope following skipped some).
    """

    time: np.ndarray
    height: np.ndarray
    velocity: np.ndarray
    oscillation: np.ndarray
    excitation: np.ndarray
    marched_periods: int


@dataclasses.dataclass(frozen=True)
class CoupledState:
    """Film and object between calls of :meth:`CoupledModel.advance` (the stepping API).

    The film and object are held at the end of the last excitation period marched; excitation periods
    start at ``epoch_s + k / f`` (k = 0, 1, ...), and the one starting at ``epoch_s + period_index / f``
    is the next to march.

    Attributes
    ----------
    vector : ndarray
        [P - 1 at the nodes at T_k and T_{k-1}, Z_k, Z_{k-1}, W_k, W_{k-1}] (non-dimensional, eq. 2;
        W = dZ/dT): the march's own state at the end of the last period. Not to be modified.
    time_s : float
        Time reached [s] (the end of the last communication step).
    epoch_s : float
        Start [s] of period 0 at the current excitation frequency.
    period_index : int
        Periods marched since ``epoch_s``.
    height : float
        Mean z over the last period marched [m] (the initial height before any).
    velocity : float
        Mean dz/dt over the last period marched [m/s] (the initial velocity before any).
    oscillation : float
        Fast oscillation amplitude of the last period marched [m] (0 before any), as in
        :class:`CoupledTrajectory`.
    """

    vector: np.ndarray
    time_s: float
    epoch_s: float
    period_index: int
    height: float
    velocity: float
    oscillation: float

    def next_period_start(self, frequency: float) -> float:
        """Start time [s] of the next period to march at ``frequency`` [Hz]."""
        return self.epoch_s + self.period_index / frequency


class CoupledModel:
    """The object on its squeeze film: eqs. (3)-(5) with the equation of motion (4).

    Parameters
    ----------
    rig : RigParameters
        Rig and gas (SI); ``rig.reference_clearance`` h0 scales the variables.
    shape : ExcitationShape
        Excitation form eps_hat(R) (eq. 7), a(r) = |a| eps_hat(r / r0).
    nodes : int
        Radial nodes of the finite-volume film (>= 5).
    steps_per_period : int
        BDF2 steps per excitation period (>= 8).
    envelope : bool
        Envelope following (projective integration on the period map) instead of marching every
        period: much faster once the transient has decayed; see :meth:`_run_envelope`.
    envelope_tolerance : float
        Local error allowed per envelope jump, relative to the slow height.
    """

    def __init__(self, rig: RigParameters, shape: ExcitationShape, nodes: int = 101, steps_per_period: int = 256,
                 envelope: bool = False, envelope_tolerance: float = 1e-6) -> None:
        if not isinstance(rig, RigParameters):
            raise InvalidParameterError("rig", rig, "a RigParameters")
        if not callable(shape) or not hasattr(shape, "slope"):
            raise InvalidParameterError("shape", shape, "an ExcitationShape")
        check_grid(nodes, steps_per_period)
        if not isinstance(envelope, bool):
            raise InvalidParameterError("envelope", envelope, "True or False")
        self.envelope = envelope
        self.envelope_tolerance = require_positive("envelope_tolerance", envelope_tolerance)
        self.rig, self.shape = rig, shape
        self.nodes, self.steps_per_period = int(nodes), int(steps_per_period)
        self.R, faces, self.volumes = radial_grid(self.nodes)
        self._faces = faces
        self._eps_nodes = np.ascontiguousarray(shape(self.R), dtype=float)
        self._eps_faces = np.ascontiguousarray(shape(faces), dtype=float)
        self._conductance = faces / self.R[1]
        h0 = rig.reference_clearance
        #: Lambda = sigma Hbar^2 = 12 mu omega r0^2 / (p_a h0^2), eq. (3)
        self.film_number = float(rig.squeeze_number(h0))

    def __repr__(self) -> str:
        return f"<CoupledModel {self.shape!r} nodes={self.nodes} steps_per_period={self.steps_per_period}>"

    def simulate(self, duration: float, excitation: Excitation, initial_height: float, initial_velocity: float = 0.0,
                 progress: Callable[[int, int], None] | None = None) -> CoupledTrajectory:
        """Release the object at ``initial_height`` and march film and object for ``duration`` s.

        Parameters
        ----------
        duration : float
            Time span [s]; rounded up to whole excitation periods.
        excitation : float or callable
            |a| [m] (the norm of eq. 7 in metres), constant or a function of time t [s], sampled
            at the start of each excitation period and held over it.
        initial_height : float
            z at release [m] (the clearance at the rim-to-rim mean position).
        initial_velocity : float
            dz/dt at release [m/s].
        progress : callable, optional
            ``progress(done, total)`` in excitation periods, about 100 times per run.

        Returns
        -------
        CoupledTrajectory

        Raises
        ------
        InvalidParameterError
            On bad input.
        ConvergenceError
            When the gap closes (H <= 0 somewhere: the full model has no contact model) or Newton fails.

        Notes
        -----
        The film starts quasi-steady: the perturbation solution (eqs. 9-11, first harmonic and mean)
        of a fixed object at ``initial_height`` under the initial |a|.
        """
        rig = self.rig
        duration = require_positive("duration", duration)
        height0 = require_positive("initial_height", initial_height)
        try:
            velocity0 = float(initial_velocity)
        except (TypeError, ValueError):
            raise InvalidParameterError("initial_velocity", initial_velocity, "a finite number (m/s)") from None
        if not math.isfinite(velocity0):
            raise InvalidParameterError("initial_velocity", initial_velocity, "a finite number (m/s)")
        if progress is not None and not callable(progress):
            raise InvalidParameterError("progress", progress, "None or a callable(done, total)")
        periods = max(1, math.ceil(duration * rig.frequency - 1e-9))
        period_starts = np.arange(periods) / rig.frequency
        excitation_values = _sample_excitation(excitation, period_starts)
        h0, omega, steps = rig.reference_clearance, rig.omega, self.steps_per_period
        amplitudes = excitation_values / h0
        state = self._initial_state(height0 / h0, velocity0 / (h0 * omega), float(amplitudes[0]))

        height, velocity = np.empty(periods), np.empty(periods)
        cos_sum, sin_sum = np.empty(periods), np.empty(periods)
        outputs = (height, velocity, cos_sum, sin_sum)
        if self.envelope:
            marched = self._run_envelope(state, amplitudes, outputs, progress)
        else:
            chunk = max(1, periods // PROGRESS_CHUNKS)
            for done in range(0, periods, chunk):
                self._march(state, amplitudes, done, min(periods, done + chunk), outputs)
                if progress is not None:
                    progress(min(periods, done + chunk), periods)
            marched = periods
        dt = 2.0 * np.pi / steps
        phases = dt * np.arange(1, steps + 1)
        time = (np.arange(periods) * 2.0 * np.pi + phases.mean()) / omega
        oscillation = 2.0 / steps * np.hypot(cos_sum, sin_sum) * h0  # |first harmonic of Z'| / 1 (omega = 1 in T)
        return CoupledTrajectory(time, height * h0, velocity * h0 * omega, oscillation, excitation_values, marched)

    # --- stepping API (co-simulation): the same march, one communication step at a time -------------
    def initial_state(self, height: float, velocity: float = 0.0, amplitude: float = 0.0,
                      time_s: float = 0.0) -> CoupledState:
        """The state :meth:`simulate` starts from: object at ``height`` [m] moving at ``velocity`` [m/s],
        quasi-steady film of the excitation |a| = ``amplitude`` [m], at time ``time_s`` [s] (period 0 starts there)."""
        height0 = require_positive("height", height)
        velocity0 = require_finite("velocity", velocity, "a finite number (m/s)")
        amplitude0 = require_amplitude("amplitude", amplitude)
        time0 = require_finite("time_s", time_s, "a finite time (s)")
        h0, omega = self.rig.reference_clearance, self.rig.omega
        vector = self._initial_state(height0 / h0, velocity0 / (h0 * omega), amplitude0 / h0)
        return CoupledState(vector, time0, time0, 0, height0, velocity0, 0.0)

    def advance(self, state: CoupledState, amplitude: float, step_s: float,
                envelope: bool | None = None) -> CoupledState:
        """March from ``state.time_s`` to ``state.time_s + step_s`` with |a| = ``amplitude`` [m] held.

        Every excitation period whose start lies in the step is marched in full with ``amplitude``
        (as :meth:`simulate` samples |a| at period starts); a step shorter than what is left of a
        period marches none and only moves the time on. So stepping through [0, T] with the
        excitation held over each step gives :meth:`simulate`'s trajectory for that piecewise-constant
        excitation (the same arithmetic: tests/test_fmu_plants.py). ``envelope`` (default: the model's)
        applies envelope following within the step (it can only jump when a step spans many bursts).

        Raises
        ------
        InvalidParameterError
            On bad input.
        ConvergenceError
            When the gap closes or Newton fails (as :meth:`simulate`).
        """
        if not isinstance(state, CoupledState):
            raise InvalidParameterError("state", type(state).__name__, "a CoupledState (from initial_state or advance)")
        if state.vector.shape != (2 * self.nodes + 4,):
            raise InvalidParameterError("state", f"{state.vector.size} values",
                                        f"a state of a model with {self.nodes} nodes")
        step = require_positive("step_s", step_s)
        amplitude = require_amplitude("amplitude", amplitude)
        envelope = self.envelope if envelope is None else envelope
        rig = self.rig
        end = state.time_s + step
        last = max(state.period_index, math.ceil((end - state.epoch_s) * rig.frequency - 1e-9))
        count = last - state.period_index
        if count == 0:
            return dataclasses.replace(state, time_s=end)
        vector = state.vector.copy()
        amplitudes = np.full(count, amplitude / rig.reference_clearance)
        outputs = tuple(np.empty(count) for _ in range(4))
        if envelope:
            self._run_envelope(vector, amplitudes, outputs, None)
        else:
            self._march(vector, amplitudes, 0, count, outputs)
        height, velocity, cos_sum, sin_sum = (float(column[-1]) for column in outputs)
        h0, steps = rig.reference_clearance, self.steps_per_period
        return CoupledState(vector, end, state.epoch_s, last, height * h0, velocity * h0 * rig.omega,
                            2.0 / steps * math.hypot(cos_sum, sin_sum) * h0)

    def adopt(self, state: CoupledState, previous: "CoupledModel") -> CoupledState:
        """``state`` of ``previous`` as a state of this model when only the excitation frequency differs.

        For a drive frequency that changes between steps: the film and object are kept as they are
        at the end of the last period (Z and P unchanged); W = dZ/dT and the BDF2 histories at T - dT
        are rescaled to the new time unit 1 / omega (first order in the step), and the next period
        starts where the previous model's next period would have started.
        """
        if not isinstance(previous, CoupledModel) \
                or (previous.nodes, previous.steps_per_period) != (self.nodes, self.steps_per_period) \
                or not np.array_equal(previous._eps_nodes, self._eps_nodes):
            raise InvalidParameterError("previous", previous, "a CoupledModel with the same nodes, steps and shape")
        if previous.rig.replace(frequency=self.rig.frequency) != self.rig:
            raise InvalidParameterError("previous", previous.rig, "a rig that differs from this one in frequency only")
        ratio = self.rig.frequency / previous.rig.frequency  # new time unit / old one: d/dT_new = d/dT_old / ratio
        nodes, vector = self.nodes, state.vector.copy()
        u_now, u_prev = vector[:nodes], vector[nodes:2 * nodes]
        z_now, z_prev, w_now, w_prev = vector[2 * nodes:]
        vector[nodes:2 * nodes] = u_now - (u_now - u_prev) / ratio
        vector[2 * nodes + 1] = z_now - (z_now - z_prev) / ratio
        vector[2 * nodes + 2] = w_now / ratio
        vector[2 * nodes + 3] = (w_now - (w_now - w_prev) / ratio) / ratio
        start = state.next_period_start(previous.rig.frequency)
        return dataclasses.replace(state, vector=vector, epoch_s=start, period_index=0)

    def _march(self, state: np.ndarray, amplitudes: np.ndarray, start: int, stop: int, outputs) -> None:
        """March periods [start, stop) in full, writing their outputs; raise on a closed gap or Newton failure."""
        rig, nodes, steps = self.rig, self.nodes, self.steps_per_period
        status, marched, step = _march_coupled(
            state, amplitudes[start:stop], self._eps_nodes, self._eps_faces, self._conductance, self.volumes,
            self.film_number, rig.stiffness_coefficient, rig.gravity_term, steps,
            *(column[start:stop] for column in outputs))
        if status != STATUS_OK:
            t_fail = (start + marched + (step + 1) / steps) / rig.frequency
            if status == STATUS_GAP:
                raise GapClosedError(
                    f"the gap closed at t = {t_fail:.6g} s (object at z = "
                    f"{state[2 * nodes] * rig.reference_clearance * 1e6:.4g} um, "
                    f"|a| = {amplitudes[start + marched] * rig.reference_clearance * 1e6:.4g} um, max eps_hat = "
                    f"{np.max(self._eps_nodes):.3g}): the full model has no contact model; use the simplified plant "
                    "for touchdown")
            raise ConvergenceError(f"Newton did not converge at t = {t_fail:.6g} s; try more steps_per_period")

    def _run_envelope(self, state: np.ndarray, amplitudes: np.ndarray, outputs, progress) -> int:
        """Projective integration on the period map (envelope following); returns the periods marched.

        Bursts of ``ENVELOPE_BURST`` full periods alternate with jumps of M periods along the last
        period-to-period change of the whole state (projective forward Euler, Gear & Kevrekidis 2003):
        X_{k+M} = X_k + M (X_k - X_{k-1}). M is the smallest of
        (i) the accuracy limit sqrt(2 tol Z / |c|), c the change of the slow height's per-period
            slope between bursts (the jump's local error is c M^2 / 2);
        (ii) the stability limits of projective Euler, mu^(burst-1) |(M + 1) mu - M| <= 1/2, for the
            modes the burst must damp: the film's slowest, mu = exp(-2 pi 5.78 Z^2 / Lambda), and the
            object's velocity mode of eq. (13), mu = exp(-2 pi C_d / Z^3);
        (iii) 1 / rate for the slow mode itself (projective Euler needs M rate < 2), with the rate
            measured from successive burst slopes while they are above round-off (no jump before);
        (iv) the run of periods with the same |a| (no jump across an excitation change).
        Skipped periods get the linear interpolation of their neighbours' outputs.
        """
        periods = amplitudes.size
        height, velocity, cos_sum, sin_sum = outputs
        burst, done, marched = ENVELOPE_BURST, 0, 0
        before = state.copy()
        last_slope, last_at, slow_rate = None, None, None
        next_report = 0
        while done < periods:
            stop = min(periods, done + burst)
            if stop - done >= 2:
                self._march(state, amplitudes, done, stop - 1, outputs)
            before[:] = state
            self._march(state, amplitudes, stop - 1, stop, outputs)
            marched += stop - done
            done = stop
            if progress is not None and done >= next_report:
                progress(done, periods)
                next_report = done + max(1, periods // PROGRESS_CHUNKS)
            if done >= periods or done < 2:
                continue
            slope = height[done - 1] - height[done - 2]
            at = done - 1.5
            jump = 0
            Z = height[done - 1]
            if last_slope is not None:
                ratio = slope / last_slope if last_slope != 0.0 else 0.0
                if abs(slope) > ENVELOPE_NOISE * Z and 0.0 < ratio < 1.0:  # a clean decay: measure its rate
                    slow_rate = -math.log(ratio) / (at - last_at)
                curvature = abs(slope - last_slope) / (at - last_at)
                accurate = math.sqrt(2.0 * self.envelope_tolerance * Z / curvature) if curvature > 0 else math.inf
                film_decay = math.exp(-2.0 * math.pi * SLOWEST_FILM_EIGENVALUE * Z**2 / self.film_number)
                stable = min(_projective_limit(film_decay, burst),
                             _projective_limit(math.exp(-2.0 * math.pi * self.rig.damping_coefficient / Z**3), burst),
                             1.0 / slow_rate if slow_rate is not None else 0.0)
                same = np.flatnonzero(amplitudes[done:] != amplitudes[done - 1])
                constant_run = int(same[0]) if same.size else periods - done
                jump = int(min(accurate, stable, constant_run - burst, ENVELOPE_MAX_JUMP))
            last_slope, last_at = slope, at
            if jump < burst:
                continue
            step = state - before
            state += jump * step
            # outputs of the skipped periods: straight lines through the last marched period
            ramp = np.arange(1, jump + 1)
            for column in outputs:
                change = column[done - 1] - column[done - 2]
                column[done:done + jump] = column[done - 1] + change * ramp if column is height or column is velocity \
                    else column[done - 1]
            done += jump
        if progress is not None:
            progress(periods, periods)
        return marched

    def _initial_state(self, Z0: float, W0: float, A0: float) -> np.ndarray:
        """[u(T=0), u(T=-dT), Z, Z(-dT), W, W(-dT)]: quasi-steady film at Z0, object moving at W0."""
        nodes, dt = self.nodes, 2.0 * np.pi / self.steps_per_period
        u_now, u_prev = np.zeros(nodes), np.zeros(nodes)
        if A0 > 0.0:
            u_now, u_prev = perturbation_film(self.shape, self.film_number / Z0**2, A0 / Z0, self.R, self._faces,
                                              (0.0, -dt)).T
        return np.concatenate((u_now, u_prev, [Z0, Z0 - W0 * dt, W0, W0]))


def _sample_excitation(excitation: Excitation, times: np.ndarray) -> np.ndarray:
    """|a| [m] at each period start, checked finite and >= 0."""
    if callable(excitation):
        values = np.array([float(excitation(float(t))) for t in times])
        bad = np.flatnonzero(~np.isfinite(values) | (values < 0))
        if bad.size:
            raise InvalidParameterError("excitation", values[bad[0]],
                                        f"finite amplitudes >= 0 m (at t = {times[bad[0]]:.6g} s)")
        return values
    return np.full(times.size, require_amplitude("excitation", excitation, or_function=True))

