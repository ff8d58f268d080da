/* The discrete PID of eqs. (21)-(22) as models/control_law.py's DiscreteControlLaw.step computes it, in C99 for
 * the host's compiled 2 kHz loop (nfal_loop.h): the same operations in the same order, so that the command is the
 * Python law's to the last bit (built with -ffp-contract=off; tests/test_compiled_loop.py holds the two equal).
 *
 * Everything the law needs that Python computes once (the decays, the lead's weights, the schedule's spline) is
 * given in nfal_law_params; the feedforward path is not carried (DiscreteControlLaw.compiled_parameters refuses
 * a law with one). No allocation, no libm.
 */
#ifndef NFAL_LAW_H
#define NFAL_LAW_H

#include <stdint.h>

/* The lift-off pair ends when it is this close to the reference (relative): control_law.LIFT_OFF_END. */
#define NFAL_LIFT_OFF_END 1e-3

typedef struct {
    double period_s, filter_rad_s, max_excitation_m, tracking_time_s;
    double reference_low_m, reference_high_m;   /* accepted references */
    double measurement_low_m, measurement_high_m;
    int32_t has_reference_pair;                 /* reference_filter_s given */
    double reference_pair_decay;                /* exp(-T / reference_filter_s) */
    int32_t has_lift_off;
    double lift_off_decay;                      /* exp(-T / lift_off_time_s) */
    int32_t has_lead;                           /* actuator_lag_s > 0 */
    double lead_held, lead_new, lead_rate;      /* the lead's backward-Euler weights */
    int32_t has_reference_zero;
    double reference_zero_ratio;
    /* the gains: a cubic spline in h / reference_clearance (knots > 0), or fixed (knots == 0) */
    int32_t knots;
    const double *knot;                         /* [knots] */
    const double *pieces;                       /* [knots - 1][3 gains][4 powers, highest first] */
    const double *slow_time_s;                  /* [knots]: 1 / p1 at each knot */
    double reference_clearance_m, omega;
    double fixed_kp, fixed_ki, fixed_kd, fixed_slow_time_s;
} nfal_law_params;

/* ControllerState without the feedforward's members; has_* stand for Python's None. */
typedef struct {
    double integrator_m, derivative_m_per_s, previous_measurement_m;
    double pair_first_m, pair_second_m, lead_input_m, lead_output_m, reference_lag_m;
    int32_t has_previous, has_pair, has_lead, lifting, has_reference_lag;
} nfal_law_state;

/* One sample: the command |a| [m] into *command and the state advanced. Returns 0, or -1 (nothing changed) if the
 * reference or the measurement is not finite or out of its range: the Python law raises there. */
int nfal_law_step(const nfal_law_params *p, nfal_law_state *s, double reference_m, double measured_m,
                  double *command);

#endif
