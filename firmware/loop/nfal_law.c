/* See nfal_law.h. Each block names the method of models/control_law.py it mirrors; keep the two in step. */
#include "nfal_law.h"

static double min2(double a, double b) { return b < a ? b : a; }  /* Python's min(a, b) */
static double max2(double a, double b) { return b > a ? b : a; }  /* Python's max(a, b) */
static int within(double x, double low, double high) { return x == x && low <= x && x <= high; }

/* GainSchedule.law_terms / FixedGains.law_terms: (k_p, k_i, k_d, 1 / p1) at the measured clearance. */
static void law_terms(const nfal_law_params *p, double height_m, double terms[4]) {
    int32_t i = 0, g;
    double x, dx;
    const double *k = p->knot;
    if (p->knots == 0) {
        terms[0] = p->fixed_kp, terms[1] = p->fixed_ki, terms[2] = p->fixed_kd, terms[3] = p->fixed_slow_time_s;
        return;
    }
    x = min2(max2(height_m / p->reference_clearance_m, k[0]), k[p->knots - 1]);  /* ScalarSpline.piece */
    while (i + 1 < p->knots && k[i + 1] <= x) i++;                             /* bisect_right - 1 */
    if (i > p->knots - 2) i = p->knots - 2;
    dx = x - k[i];
    for (g = 0; g < 3; g++) {                                                    /* ScalarSpline.values_in */
        const double *c = p->pieces + (i * 3 + g) * 4;
        terms[g] = ((c[0] * dx + c[1]) * dx + c[2]) * dx + c[3];
    }
    terms[1] = terms[1] * p->omega;
    terms[2] = terms[2] / p->omega;
    terms[3] = p->slow_time_s[i] + (p->slow_time_s[i + 1] - p->slow_time_s[i]) * dx / (k[i + 1] - k[i]);
}

int nfal_law_step(const nfal_law_params *p, nfal_law_state *s, double reference_m, double measured_m,
                  double *command) {
    nfal_law_state n;
    double target, decay, previous, ts = p->period_s, wl = p->filter_rad_s, terms[4];
    double error, unsaturated, clamped, integrator;
    if (!within(reference_m, p->reference_low_m, p->reference_high_m)
        || !within(measured_m, p->measurement_low_m, p->measurement_high_m))
        return -1;
    n = *s;
    if (!s->has_previous && p->has_lift_off && measured_m < p->reference_low_m) {  /* lift off from nothing */
        n.integrator_m = 0.0, n.derivative_m_per_s = 0.0, n.has_lead = 0, n.has_reference_lag = 0;
        n.has_pair = 1, n.pair_first_m = measured_m, n.pair_second_m = measured_m, n.lifting = 1;
    }
    /* _shaped_reference */
    if (n.lifting ? !p->has_lift_off : !p->has_reference_pair) {
        target = reference_m, n.has_pair = 0, n.lifting = 0;
    } else {
        double first = n.has_pair ? n.pair_first_m : reference_m, second = n.has_pair ? n.pair_second_m : reference_m;
        decay = n.lifting ? p->lift_off_decay : p->reference_pair_decay;
        first = reference_m + (first - reference_m) * decay;
        second = first + (second - first) * decay;
        if (n.lifting && (reference_m - second < 0 ? second - reference_m : reference_m - second)
                         <= NFAL_LIFT_OFF_END * reference_m)
            n.lifting = 0;
        target = second;
        n.has_pair = n.lifting || p->has_reference_pair;
        n.pair_first_m = first, n.pair_second_m = second;
    }
    previous = n.has_previous ? n.previous_measurement_m : measured_m;
    n.derivative_m_per_s = (1.0 - ts * wl) * n.derivative_m_per_s + wl * (measured_m - previous);
    law_terms(p, measured_m, terms);
    /* _weighted_reference */
    if (!p->has_reference_zero || terms[1] <= 0.0) {
        n.has_reference_lag = 0;
    } else {
        double pi_time = terms[0] / terms[1];
        double weight = min2(1.0, p->reference_zero_ratio * terms[3] / pi_time);
        double lag_decay = max2(0.0, 1.0 - p->period_s / pi_time);
        n.reference_lag_m = lag_decay * (n.has_reference_lag ? n.reference_lag_m : measured_m)
                            + (1.0 - lag_decay) * target;
        n.has_reference_lag = 1;
        target = weight * target + (1.0 - weight) * n.reference_lag_m;
    }
    /* step: the PID with saturation and back-calculation */
    integrator = n.integrator_m + 0.0;
    error = target - measured_m;
    unsaturated = terms[0] * error + integrator - terms[2] * (n.derivative_m_per_s - 0.0);
    clamped = min2(max2(unsaturated, 0.0), p->max_excitation_m);
    n.integrator_m = integrator + (ts * terms[1] * error + (ts / p->tracking_time_s) * (clamped - unsaturated));
    /* _lead */
    if (!p->has_lead) {
        *command = clamped, n.has_lead = 0;
    } else {
        double last_input = n.has_lead ? n.lead_input_m : clamped, last_output = n.has_lead ? n.lead_output_m : clamped;
        double output = p->lead_held * last_output + p->lead_new * clamped + p->lead_rate * (clamped - last_input);
        *command = min2(max2(output, 0.0), p->max_excitation_m);
        n.has_lead = 1, n.lead_input_m = clamped, n.lead_output_m = output;
    }
    n.has_previous = 1, n.previous_measurement_m = measured_m;
    *s = n;
    return 0;
}
