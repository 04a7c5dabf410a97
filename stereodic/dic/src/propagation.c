/* Reliability-guided propagation of initial guesses over a grid of points (Pan, "Reliability-guided
 * digital image correlation for image deformation measurement", Appl. Opt. 48, 2009), solved in parallel
 * batches.
 *
 * Points sit on a (ny, nx) grid (index k = row * nx + col) at any positions (xs[k], ys[k]) of the
 * reference image. From the points already solved well, the pending 4-neighbours enter a priority queue
 * keyed by the ZNCC of the neighbour that queued them (ties: the lower index first). The BATCH most
 * reliable candidates are taken at a time; each starts from the warp of its best solved neighbour
 * (highest ZNCC) moved to its own position, and the batch is solved in parallel. */
#include <stdlib.h>

#include "propagation.h"

#define BATCH 256   /* points solved in parallel per step: enough for the threads, small against the front */
#define FEW 8       /* fewer points than this are solved by the calling thread: waking the others costs more */

int solve_many(const Problem *pb, Points *pts, const int64_t *idx, long count)
{
    const int n = pb->nparams;
    int failed = 0;
    #pragma omp parallel if (count >= FEW)
    {
        Work w;
        const int ok = work_alloc(&w, pb) == 0;
        if (!ok) {
            #pragma omp atomic write
            failed = 1;
        }
        #pragma omp for schedule(dynamic, 4)
        for (long t = 0; t < count; ++t) {
            if (!ok)
                continue;
            const long k = idx ? (long)idx[t] : t;
            const double x0 = pts->xs[k], y0 = pts->ys[k];
            const double *row = NULL;
            if (pb->cache) {   /* a row kept for another position is not this point's */
                row = pb->cache + (pb->rows ? pb->rows[k] : k) * reference_width(n);
                if (row[REF_X] != x0 || row[REF_Y] != y0)
                    row = NULL;
            }
            int it;
            pts->status[k] = (int8_t)solve_point(pb, &w, x0, y0, row, pts->P + k * n, pts->zncc + k, &it);
            pts->iters[k] = it;
        }
        if (ok)
            work_free(&w);
    }
    return failed ? -1 : 0;
}

/* status_many, or with `rows` (count, reference_width) the reference data of every point. */
int status_many(const Problem *pb, const double *xs, const double *ys, long count, int8_t *status, double *rows)
{
    const long width = reference_width(pb->nparams);
    int failed = 0;
    #pragma omp parallel if (count >= FEW)
    {
        Work w;
        const int ok = work_alloc(&w, pb) == 0;
        if (!ok) {
            #pragma omp atomic write
            failed = 1;
        }
        #pragma omp for schedule(dynamic, 16)
        for (long k = 0; k < count; ++k)
            if (ok)
                status[k] = (int8_t)(rows ? reference_data(pb, &w, xs[k], ys[k], rows + k * width)
                                          : reference_status(pb, &w, xs[k], ys[k]));
        if (ok)
            work_free(&w);
    }
    return failed ? -1 : 0;
}

/* A max-heap of candidates by (key, then lower index). */
typedef struct {
    double key;
    long q;
} Entry;

typedef struct {
    Entry *e;
    long size, cap;
} Heap;

static inline int before(Entry a, Entry b)
{
    return a.key > b.key || (a.key == b.key && a.q < b.q);
}

static int heap_push(Heap *h, double key, long q)
{
    if (h->size == h->cap) {
        const long cap = h->cap ? 2 * h->cap : 1024;
        Entry *e = realloc(h->e, sizeof(Entry) * (size_t)cap);
        if (!e)
            return -1;
        h->e = e;
        h->cap = cap;
    }
    long i = h->size++;
    const Entry x = {key, q};
    while (i > 0) {
        const long parent = (i - 1) / 2;
        if (!before(x, h->e[parent]))
            break;
        h->e[i] = h->e[parent];
        i = parent;
    }
    h->e[i] = x;
    return 0;
}

static Entry heap_pop(Heap *h)
{
    const Entry top = h->e[0], last = h->e[--h->size];
    long i = 0;
    for (;;) {
        long c = 2 * i + 1;
        if (c >= h->size)
            break;
        if (c + 1 < h->size && before(h->e[c + 1], h->e[c]))
            ++c;
        if (!before(h->e[c], last))
            break;
        h->e[i] = h->e[c];
        i = c;
    }
    if (h->size > 0)
        h->e[i] = last;
    return top;
}

static int push_neighbours(Heap *h, long k, long nx, long ny, long stride, const int8_t *done, double key)
{
    const long r = k / nx, c = k - r * nx;
    const long dr[4] = {stride, -stride, 0, 0}, dc[4] = {0, 0, stride, -stride};
    for (int d = 0; d < 4; ++d) {
        const long rr = r + dr[d], cc = c + dc[d];
        if (0 <= rr && rr < ny && 0 <= cc && cc < nx && done[rr * nx + cc] == 0)
            if (heap_push(h, key, rr * nx + cc) < 0)
                return -1;
    }
    return 0;
}

long propagate(const Problem *pb, Points *pts, long npts, long nx, long stride, int8_t *done)
{
    const long ny = npts / nx;
    const int n = pb->nparams;
    const long dr[4] = {stride, -stride, 0, 0}, dc[4] = {0, 0, stride, -stride};
    Heap heap = {NULL, 0, 0};
    int64_t batch[BATCH];
    long solved = 0;
    for (long k = 0; k < npts; ++k)
        if (done[k] == 1 && pts->status[k] == OK && push_neighbours(&heap, k, nx, ny, stride, done, pts->zncc[k]) < 0)
            goto oom;
    while (heap.size > 0) {
        long nb = 0;
        while (heap.size > 0 && nb < BATCH) {
            const long q = heap_pop(&heap).q;
            if (done[q] == 0) {
                done[q] = 2;   /* taken */
                batch[nb++] = q;
            }
        }
        for (long t = 0; t < nb; ++t) {
            const long q = batch[t], r = q / nx, c = q - r * nx;
            long best = -1;
            double bestz = -2.0;
            for (int d = 0; d < 4; ++d) {
                const long rr = r + dr[d], cc = c + dc[d];
                if (0 <= rr && rr < ny && 0 <= cc && cc < nx) {
                    const long s = rr * nx + cc;
                    if (done[s] == 1 && pts->status[s] == OK && pts->zncc[s] > bestz) {
                        bestz = pts->zncc[s];
                        best = s;
                    }
                }
            }
            shift_warp(pts->P + best * n, n, pts->xs[q] - pts->xs[best], pts->ys[q] - pts->ys[best], pts->P + q * n);
        }
        if (solve_many(pb, pts, batch, nb) < 0)
            goto oom;
        for (long t = 0; t < nb; ++t) {
            const long q = batch[t];
            done[q] = 1;
            if (pts->status[q] == OK && push_neighbours(&heap, q, nx, ny, stride, done, pts->zncc[q]) < 0)
                goto oom;
        }
        solved += nb;
    }
    free(heap.e);
    return solved;
oom:
    free(heap.e);
    return -1;
}

long guesses_from_lattice(const Points *pts, int nparams, long npts, long nx, long stride, const int8_t *done,
                          int64_t *out)
{
    const long ny = npts / nx;
    const int n = nparams;
    double moved[12];
    long count = 0;
    for (long q = 0; q < npts; ++q) {
        if (done[q] != 0)
            continue;
        const long r = q / nx, c = q - r * nx, r0 = (r / stride) * stride, c0 = (c / stride) * stride;
        double *Pq = pts->P + q * n, wsum = 0.0;
        for (long rr = r0; rr <= r0 + stride; rr += stride) {
            for (long cc = c0; cc <= c0 + stride; cc += stride) {
                if (rr >= ny || cc >= nx)
                    continue;
                const long s = rr * nx + cc;
                if (done[s] != 1 || pts->status[s] != OK)
                    continue;
                const double w = (1.0 - labs(rr - r) / (double)stride) * (1.0 - labs(cc - c) / (double)stride) + 1e-6;
                shift_warp(pts->P + s * n, n, pts->xs[q] - pts->xs[s], pts->ys[q] - pts->ys[s], moved);
                if (wsum == 0.0)
                    for (int a = 0; a < n; ++a)
                        Pq[a] = 0.0;
                for (int a = 0; a < n; ++a)
                    Pq[a] += w * moved[a];
                wsum += w;
            }
        }
        if (wsum > 0.0) {
            for (int a = 0; a < n; ++a)
                Pq[a] /= wsum;
            out[count++] = q;
        }
    }
    return count;
}
