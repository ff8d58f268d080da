/* ucrtbase.dll for the Windows test bench under wine 8.0 (nfal/apps/wine.py): never part of an FMU.
 *
 * wine 8.0's ucrtbase leaves C99 complex functions unimplemented (cexp, carg, csin, ccos, ctan, their hyperbolic
 * forms, cpow: a call aborts the process), and numpy's and scipy's MSVC builds import them. This DLL implements the
 * UCRT's complex math functions (c*, and their f and l forms) with mingw-w64's libm; nfal/apps/wine.py forwards each other
 * export, _Cbuild and _Cmulcc among them (wine has those), to wine's own ucrtbase, copied beside it as
 * ucrtbase_wine.dll (a generated .def).
 *
 * The UCRT's complex types are structs (_Dcomplex, _Fcomplex; _Lcomplex holds doubles: MSVC's long double is a
 * double), which the Windows x64 calling convention passes and returns as GCC does the same structs.
 */
#include <complex.h>

typedef struct { double v[2]; } dcomplex; /* _Dcomplex and _Lcomplex */
typedef struct { float v[2]; } fcomplex;  /* _Fcomplex */

static double _Complex from_d(dcomplex z) { return __builtin_complex(z.v[0], z.v[1]); }
static dcomplex to_d(double _Complex z) { dcomplex r = {{creal(z), cimag(z)}}; return r; }
static float _Complex from_f(fcomplex z) { return __builtin_complex(z.v[0], z.v[1]); }
static fcomplex to_f(float _Complex z) { fcomplex r = {{crealf(z), cimagf(z)}}; return r; }

/* name, namef, namel: a complex function of one complex argument */
#define COMPLEX(name) \
    dcomplex nfal_##name(dcomplex z) { return to_d(name(from_d(z))); } \
    fcomplex nfal_##name##f(fcomplex z) { return to_f(name##f(from_f(z))); } \
    dcomplex nfal_##name##l(dcomplex z) { return to_d(name(from_d(z))); }
/* name, namef, namel: a real function of one complex argument */
#define REAL(name) \
    double nfal_##name(dcomplex z) { return name(from_d(z)); } \
    float nfal_##name##f(fcomplex z) { return name##f(from_f(z)); } \
    double nfal_##name##l(dcomplex z) { return name(from_d(z)); }

COMPLEX(cacos)
COMPLEX(cacosh)
COMPLEX(casin)
COMPLEX(casinh)
COMPLEX(catan)
COMPLEX(catanh)
COMPLEX(ccos)
COMPLEX(ccosh)
COMPLEX(cexp)
COMPLEX(clog)
COMPLEX(conj)
COMPLEX(cproj)
COMPLEX(csin)
COMPLEX(csinh)
COMPLEX(csqrt)
COMPLEX(ctan)
COMPLEX(ctanh)
REAL(cabs)
REAL(carg)
REAL(cimag)
REAL(creal)

#define LN10 2.302585092994045684
dcomplex nfal_clog10(dcomplex z) { return to_d(clog(from_d(z)) / LN10); }
fcomplex nfal_clog10f(fcomplex z) { return to_f(clogf(from_f(z)) / (float)LN10); }
dcomplex nfal_clog10l(dcomplex z) { return nfal_clog10(z); }
dcomplex nfal_cpow(dcomplex x, dcomplex y) { return to_d(cpow(from_d(x), from_d(y))); }
fcomplex nfal_cpowf(fcomplex x, fcomplex y) { return to_f(cpowf(from_f(x), from_f(y))); }
dcomplex nfal_cpowl(dcomplex x, dcomplex y) { return nfal_cpow(x, y); }
