"""The loop's settings: the paper's Table 2, and the values it leaves open beside them (docs/assumptions.md).

Every default of the controller, the sensor chain and the PLL (in the models, the FMUs, the command line and
``ssp/table2.ssv``, which a test holds equal to the FMUs) is one of these; no module imports anything, so an
FMU that needs only a constant loads nothing else.
"""

#: Table 2: the closed loop's -3 dB cut-off of eq. (23) [Hz].
CLOSED_LOOP_CUTOFF_HZ = 10.0
#: Table 2: the derivative filter's cut-off of eq. (22) [Hz].
FILTER_CUTOFF_HZ = 300.0
#: Table 2: the sensor's analog anti-aliasing filter [Hz].
ANALOG_FILTER_CUTOFF_HZ = 2000.0
#: Table 2: the sampling rate of the controller, the sensor chain and the PLL [Hz].
SAMPLING_RATE_HZ = 2000.0
#: Sec. 4.1: the measurement noise's peak (3 sigma, the clip level) [m].
NOISE_PEAK_M = 2e-6
#: The noise's colouring cut-off [Hz] (assumed: the paper names coloured noise, not its band).
NOISE_CUTOFF_HZ = 300.0
#: The work range of Sec. 4 [m]: the default schedule's and maps' heights, and the accepted references.
WORK_RANGE_M = (50e-6, 200e-6)
#: The reference of Figs. 9-10 [m]: the staircase's levels (its first is where the loop starts).
STAIRCASE_LEVELS_M = (60e-6, 100e-6, 140e-6, 180e-6, 140e-6, 100e-6, 60e-6)
#: The design height of the fixed (non-scheduled) controller of Figs. 9-10 [m].
FIXED_DESIGN_HEIGHT_M = 120e-6
#: The actuator limit |a|_max [m]: 1.6 x the 6.2 um the paper's rig needs to hold 200 um (eq. 16), above the
#: 7 um of Table 1's curve (a); not given by the paper.
MAX_EXCITATION_M = 10e-6
#: The law's reference zero, in slow-pole time constants (models/control_law.py; not the paper's): at 1 it cancels
#: one of the slow double pole, so the linear loop's step response has no overshoot (docs/controller.md, 6c).
REFERENCE_ZERO_RATIO = 1.0
