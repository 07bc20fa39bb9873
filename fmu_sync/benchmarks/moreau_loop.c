/* Baseline for the core speed benchmark: the Moreau midpoint scheme for the
 * 1-DOF impact oscillator  m q'' + c q' + k q = f0 + F cos(Omega t + phi),
 * q >= 0, written as a plain C loop with the same operation order as
 * fmu_sync.core.moreau.integrate1 (so both print the same final state).
 *
 * usage: moreau_loop m k c f0 F Omega phi e q0 u0 dt n_steps
 * prints: seconds q u impacts
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define FLUSH 1e-280

int main(int argc, char **argv) {
    if (argc != 13) {
        fprintf(stderr, "usage: %s m k c f0 F Omega phi e q0 u0 dt n_steps\n", argv[0]);
        return 2;
    }
    double m = atof(argv[1]), k = atof(argv[2]), c = atof(argv[3]), f0 = atof(argv[4]);
    double F = atof(argv[5]), Omega = atof(argv[6]), phi = atof(argv[7]), e = atof(argv[8]);
    double q = atof(argv[9]), u = atof(argv[10]), dt = atof(argv[11]);
    long n = atol(argv[12]);
    double Minv = 1.0 / m, half = 0.5 * dt;
    long impacts = 0;
    struct timespec a, b;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (long i = 0; i < n; i++) {
        double t = 0.0 + i * dt;
        double qM = q + half * u;
        double h = f0;
        h -= k * qM + c * u;
        h += F * cos(Omega * (t + half) + phi);
        double uf = u + dt * (Minv * h);
        if (qM <= 0.0) {
            double xi = uf + e * u;
            if (xi < 0.0) {
                uf += Minv * (-xi / Minv);
                impacts++;
            }
        }
        u = uf;
        q = qM + half * uf;
        if (fabs(q) < FLUSH) q = 0.0;
        if (fabs(u) < FLUSH) u = 0.0;
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    double s = (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
    printf("%.9f %.17g %.17g %ld\n", s, q, u, impacts);
    return 0;
}
