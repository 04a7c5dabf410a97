/* The raster cells inside the triangles of a structured grid of points (see raster.c). */
#ifndef STEREODIC_RASTER_H
#define STEREODIC_RASTER_H

#include <stdint.h>

/* See raster.c. Returns the number of cells found. */
long grid_cells(const double *px, const double *py, long ny, long nx, double longest, long height, long width,
                int64_t *triangle, double *weights);

#endif
