/* The raster cells inside the triangles of a structured grid of points (stereodic.dic.maps.grid_cells,
 * which documents the result). Serial: it runs in the forked children that draw maps, which must not
 * start OpenMP threads. */
#include "raster.h"

#include <math.h>

#define TOL 1e-9 /* barycentric weights this far below 0 still count as inside: a cell on a side is kept */

/* The grid points px, py (ny * nx, row-major; in raster cells: cell (i, j) is centred at (j, i); NaN: not
 * placed) make two triangles per square of neighbouring points, (r, c), (r, c+1), (r+1, c) and (r, c+1),
 * (r+1, c+1), (r+1, c), numbered 2 * (r * (nx - 1) + c) + {0, 1}; a triangle with a corner not placed,
 * no area or a side longer than `longest` (cells) is left out. For each cell of the height x width
 * raster inside a triangle (the first in that numbering where it is inside more than one: a cell on a
 * shared side), triangle[cell] gets the triangle's number and weights[2 * cell], [2 * cell + 1] the
 * barycentric weights of its first two corners (the third's is 1 minus both); the other cells are left
 * as they are (the caller fills triangle with -1). */
/* v limited to -1 .. n, as a long. */
static long clamp(double v, long n)
{
    return (long)fmin(fmax(v, -1.0), (double)n);
}

long grid_cells(const double *px, const double *py, long ny, long nx, double longest, long height, long width,
                int64_t *triangle, double *weights)
{
    long found = 0;
    for (long r = 0; r + 1 < ny; ++r) {
        for (long c = 0; c + 1 < nx; ++c) {
            const long a = r * nx + c, b = a + 1, d = a + nx, e = d + 1;
            const long corners[2][3] = {{a, b, d}, {b, e, d}};
            for (int t = 0; t < 2; ++t) {
                const double x0 = px[corners[t][0]], x1 = px[corners[t][1]], x2 = px[corners[t][2]];
                const double y0 = py[corners[t][0]], y1 = py[corners[t][1]], y2 = py[corners[t][2]];
                const double side = fmax(hypot(x0 - x2, y0 - y2), fmax(hypot(x1 - x0, y1 - y0), hypot(x2 - x1, y2 - y1)));
                const double det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2);
                if (!isfinite(det) || fabs(det) <= 1e-12 || !(side <= longest))
                    continue;
                const double a0 = (y1 - y2) / det, b0 = (x2 - x1) / det, a1 = (y2 - y0) / det, b1 = (x0 - x2) / det;
                /* the cells of the triangle's box, clamped to the raster (bounds first: a corner far off it) */
                const long j0 = clamp(ceil(fmin(x0, fmin(x1, x2))), width), j1 = clamp(floor(fmax(x0, fmax(x1, x2))), width);
                const long i0 = clamp(ceil(fmin(y0, fmin(y1, y2))), height), i1 = clamp(floor(fmax(y0, fmax(y1, y2))), height);
                const int64_t number = 2 * (r * (nx - 1) + c) + t;
                for (long i = i0 < 0 ? 0 : i0; i <= i1 && i < height; ++i) {
                    for (long j = j0 < 0 ? 0 : j0; j <= j1 && j < width; ++j) {
                        const long cell = i * width + j;
                        if (triangle[cell] >= 0)
                            continue;
                        const double w0 = a0 * (j - x2) + b0 * (i - y2), w1 = a1 * (j - x2) + b1 * (i - y2);
                        if (w0 >= -TOL && w1 >= -TOL && w0 + w1 <= 1.0 + TOL) {
                            triangle[cell] = number;
                            weights[2 * cell] = w0;
                            weights[2 * cell + 1] = w1;
                            ++found;
                        }
                    }
                }
            }
        }
    }
    return found;
}
