/* The P-I model of eq. (3) over a whole signal, in plain C: every operator at every sample, the
 * dense reference of the pi-* rows of `make bench` (compiled by benchmarks/run.py with the system
 * gcc, -O3 -march=native, with and without -ffast-math). Same recursion as
 * piezohyst.models.play.pi_simulate_dense. */
#include <stddef.h>

void pi_simulate(const double *u, size_t n_samples, const double *r, const double *w,
                 double *z, size_t n_ops, double *y)
{
    for (size_t k = 0; k < n_samples; ++k) {
        const double x = u[k];
        double acc = 0.0;
        for (size_t i = 0; i < n_ops; ++i) {
            const double lo = x - r[i], hi = x + r[i];
            double zi = z[i];
            if (zi < lo) zi = lo; else if (zi > hi) zi = hi;
            z[i] = zi;
            acc += w[i] * zi;
        }
        y[k] = acc;
    }
}
