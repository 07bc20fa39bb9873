/* Baseline for the core speed benchmark: the Moreau midpoint scheme for the
 * 1-DOF impact oscillator  m q'' + c q' + k q = f0 + F cos(Omega t + phi),
 * q >= 0, written as a plain C loop with the same operations in the same order
 * as fmu_sync.core.moreau.integrate1 (step1_h; cos path or phasor path), so
 * that both print the same final state, bit for bit. The benchmark compiles it
 * for the host CPU like numba does (-O3 -march=native) and without
 * floating-point contraction (-ffp-contract=off: numba does not fuse a*b+c into
 * an FMA either; with FMAs the results differ in the last bits).
 *
 * The same loop runs the core's default scheme, trapezoid (theta = 1/2: the coefficients of
 * S = M + a C + a^2 K in place of M, a = theta dt; step_coeffs1's products), when the last
 * argument theta is > 0 (0: the midpoint).
 *
 * usage: moreau_loop m k c f0 F Omega phi e q0 u0 dt n_steps phasor theta
 * prints: seconds q u impacts
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define FLUSH 1e-280
#define PHASOR_SYNC 64
#define BLOCK 100000 /* record_every of the numba run: a block end flushes */

static double flush(double x) { return fabs(x) < FLUSH ? 0.0 : x; }

int main(int argc, char **argv) {
    if (argc != 15) {
        fprintf(stderr, "usage: %s m k c f0 F Omega phi e q0 u0 dt n_steps phasor theta\n", argv[0]);
        return 2;
    }
    double m = atof(argv[1]), k = atof(argv[2]), c = atof(argv[3]), f0 = atof(argv[4]);
    double F = atof(argv[5]), Omega = atof(argv[6]), phi = atof(argv[7]), e = atof(argv[8]);
    double q = atof(argv[9]), u = atof(argv[10]), dt = atof(argv[11]);
    long n = atol(argv[12]);
    int phasor = atoi(argv[13]);
    double theta = atof(argv[14]);
    /* the system's arrays (w = 1, g0 = 0, B = 1, tau = 0) and step1_h's coefficients */
    double Minv = 1.0 / m, w = 1.0, g0 = 0.0, B = 1.0, tau = 0.0, t0 = 0.0;
    double a = theta > 0.0 ? theta * dt : 0.5 * dt;
    double X = theta > 0.0 ? 1.0 / ((m + a * c) + (a * a) * k) : Minv; /* S^-1 (theta_matrices) or M^-1 */
    double iw = X * w, WX = w * iw;
    double K = k, CK = c + a * k, G1 = dt * X, G2 = a * G1, aiw = a * iw, hd = 0.5 * dt;
    double hb = f0 + B * tau;
    double cr = cos(Omega * dt), sr = sin(Omega * dt), c0 = 0.0, s0 = 0.0;
    long impacts = 0;
    struct timespec ta, tb;
    clock_gettime(CLOCK_MONOTONIC, &ta);
    long i = 0, to_rec = BLOCK, to_sync = 0;
    while (i < n) {
        if (phasor && to_sync == 0) {
            double x = Omega * ((t0 + i * dt) + a) + phi;
            c0 = cos(x);
            s0 = sin(x);
            to_sync = PHASOR_SYNC;
        }
        long mm = to_rec < n - i ? to_rec : n - i;
        if (phasor && to_sync < mm) mm = to_sync;
        for (long j = i; j < i + mm; j++) {
            double fc;
            if (phasor) {
                fc = F * c0;
                double cn = c0 * cr - s0 * sr;
                s0 = s0 * cr + c0 * sr;
                c0 = cn;
            } else {
                fc = F * cos(Omega * ((t0 + j * dt) + a) + phi);
            }
            double y = (hb + fc) - (K * q + CK * u);
            double g = g0;
            g += w * (q + hd * u);
            double uf = u + G1 * y;
            double P = 0.0;
            if (g <= 0.0) {
                double xi = 0.0;
                xi += w * uf;
                double xu = 0.0;
                xu += w * u;
                xi = xi + e * xu;
                if (xi < 0.0) {
                    P = -xi / WX;
                    uf += iw * P;
                    impacts++;
                }
            }
            double qn = q + (dt * u + G2 * y);
            if (P > 0.0) qn = qn + aiw * P;
            if (g <= 0.0) {
                qn = flush(qn);
                uf = flush(uf);
            }
            q = qn;
            u = uf;
        }
        i += mm;
        to_rec -= mm;
        to_sync -= mm;
        q = flush(q);
        u = flush(u);
        if (to_rec == 0) to_rec = BLOCK;
    }
    clock_gettime(CLOCK_MONOTONIC, &tb);
    double s = (double)(tb.tv_sec - ta.tv_sec) + 1e-9 * (double)(tb.tv_nsec - ta.tv_nsec);
    printf("%.9f %.17g %.17g %ld\n", s, q, u, impacts);
    return 0;
}
