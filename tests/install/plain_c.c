/* A C file compiled with the package's include directories on its path: the
   C library's <math.h> must be found, not a header of progskin's. */
#include <math.h>
#include <error.h>

double plain_c_hypot(double x, double y) { return sqrt(x * x + y * y); }
