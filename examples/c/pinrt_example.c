/*
 * pinrt_example: open a pin file through the C ABI and sample it.
 *
 *   pinrt_example FILE.pin RAYS SEED [DUMP]
 *
 * Prints the grid's description, a few sample values, the error message for a file that does
 * not exist, and the queries per second of the batched transmittance and distance calls.
 * The rays are random lines through the grid's world box (a fixed xorshift generator, so runs
 * are repeatable). With DUMP, writes the rays (32-byte PinrtRay records) followed by the
 * transmittances and distances (RAYS floats each) to that file, so a test can replay the same
 * rays through the Rust sampler and compare bits.
 *
 * Build: cc -O2 -I capi/include examples/c/pinrt_example.c target/release/libpinrt_capi.a \
 *           -lpthread -ldl -lm -o pinrt_example
 */
#include <inttypes.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pinrt.h"

static uint32_t rng_state = 0x9e3779b9u;

/* xorshift32: a repeatable stream of uniform floats in [0, 1). */
static float next_uniform(void) {
  rng_state ^= rng_state << 13;
  rng_state ^= rng_state >> 17;
  rng_state ^= rng_state << 5;
  return (float)(rng_state >> 8) * (1.0f / 16777216.0f);
}

static double now_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int fail(const char *what, PinrtStatus st) {
  fprintf(stderr, "%s failed (status %d): %s\n", what, (int)st, pinrt_last_error());
  return 1;
}

/* A ray from a random point on a box 1.5x the grid's world box towards a random point inside
 * the grid box; every third ray stops half way (a finite t_max), the rest run to the exit. */
static PinrtRay random_ray(const PinrtDesc *d, size_t i) {
  PinrtRay r;
  float from[3], to[3], dir[3];
  for (int a = 0; a < 3; a++) {
    double lo = d->world_min[a], hi = d->world_max[a];
    double c = 0.5 * (lo + hi), h = 0.75 * (hi - lo);
    from[a] = (float)(c + h * (2.0 * next_uniform() - 1.0));
    to[a] = (float)(lo + (hi - lo) * next_uniform());
  }
  /* Push the start onto the outer box's surface along a random axis. */
  int axis = (int)(next_uniform() * 3.0f) % 3;
  double c = 0.5 * (d->world_min[axis] + d->world_max[axis]);
  double h = 0.75 * (d->world_max[axis] - d->world_min[axis]);
  from[axis] = (float)(next_uniform() < 0.5f ? c - h : c + h);
  float len = 0.0f;
  for (int a = 0; a < 3; a++) {
    dir[a] = to[a] - from[a];
    len += dir[a] * dir[a];
  }
  len = sqrtf(len);
  for (int a = 0; a < 3; a++) {
    r.origin[a] = from[a];
    r.dir[a] = len > 0.0f ? dir[a] / len : 0.0f;
  }
  r.t_max = (i % 3 == 2) ? 0.5f * len : INFINITY;
  r.pad = 0;
  return r;
}

int main(int argc, char **argv) {
  if (argc < 4) {
    fprintf(stderr, "usage: %s FILE.pin RAYS SEED [DUMP]\n", argv[0]);
    return 2;
  }
  const char *path = argv[1];
  size_t n = (size_t)strtoull(argv[2], NULL, 10);
  uint32_t seed = (uint32_t)strtoul(argv[3], NULL, 10);
  if (n == 0) {
    fprintf(stderr, "%s: RAYS must be a positive number\n", argv[0]);
    return 2;
  }
  printf("pinrt %s\n", pinrt_version());

  /* Errors come back as a status plus a one-line message naming the file. */
  PinrtGrid *missing = NULL;
  PinrtStatus st = pinrt_open("does-not-exist.pin", &missing);
  printf("missing file: status %d, message: %s\n", (int)st, pinrt_last_error());

  PinrtGrid *grid = NULL;
  st = pinrt_open(path, &grid);
  if (st != PINRT_STATUS_OK) return fail("pinrt_open", st);
  PinrtDesc d;
  st = pinrt_describe(grid, &d);
  if (st != PINRT_STATUS_OK) return fail("pinrt_describe", st);
  printf("grid %ux%ux%u cells, %u direction cells, %u pins per entry, %" PRIu64 " pins, %" PRIu64
         " bytes, mapped %u\n",
         d.dims[0], d.dims[1], d.dims[2], d.direction_cells, d.pins_per_entry, d.pin_count,
         d.file_bytes, d.mapped);
  printf("world box [%g %g %g] - [%g %g %g]\n", d.world_min[0], d.world_min[1], d.world_min[2],
         d.world_max[0], d.world_max[1], d.world_max[2]);

  PinrtRay *rays = malloc(n * sizeof *rays);
  float *trans = malloc(n * sizeof *trans);
  float *dist = malloc(n * sizeof *dist);
  float *check = malloc(n * sizeof *check);
  if (!rays || !trans || !dist || !check) {
    fprintf(stderr, "out of memory for %zu rays\n", n);
    return 1;
  }
  for (size_t i = 0; i < n; i++) rays[i] = random_ray(&d, i);

  double t0 = now_seconds();
  st = pinrt_transmittance(grid, NULL, rays, n, seed, 0, trans);
  double t1 = now_seconds();
  if (st != PINRT_STATUS_OK) return fail("pinrt_transmittance", st);
  st = pinrt_sample_distance(grid, NULL, rays, n, seed, 0, dist);
  double t2 = now_seconds();
  if (st != PINRT_STATUS_OK) return fail("pinrt_sample_distance", st);

  /* The same file from memory gives the same numbers. */
  FILE *f = fopen(path, "rb");
  if (!f) {
    fprintf(stderr, "%s: cannot reopen\n", path);
    return 1;
  }
  unsigned char *bytes = malloc((size_t)d.file_bytes);
  if (!bytes || fread(bytes, 1, (size_t)d.file_bytes, f) != (size_t)d.file_bytes) {
    fprintf(stderr, "%s: cannot read %" PRIu64 " bytes\n", path, d.file_bytes);
    return 1;
  }
  fclose(f);
  PinrtGrid *mem = NULL;
  st = pinrt_open_memory(bytes, (size_t)d.file_bytes, &mem);
  free(bytes); /* the library copied the bytes */
  if (st != PINRT_STATUS_OK) return fail("pinrt_open_memory", st);
  st = pinrt_transmittance(mem, NULL, rays, n, seed, 0, check);
  if (st != PINRT_STATUS_OK) return fail("pinrt_transmittance (memory)", st);
  size_t differ = 0;
  for (size_t i = 0; i < n; i++) differ += memcmp(&check[i], &trans[i], sizeof(float)) != 0;
  printf("memory copy differs on %zu of %zu rays\n", differ, n);
  pinrt_close(mem);

  double mean = 0.0;
  size_t hits = 0;
  for (size_t i = 0; i < n; i++) {
    mean += trans[i];
    hits += isfinite(dist[i]);
  }
  printf("mean transmittance %.6f, collisions %zu of %zu\n", mean / (double)n, hits, n);
  printf("ray 0: T = %.9g, distance = %.9g\n", trans[0], dist[0]);
  printf("queries/s transmittance %.0f distance %.0f\n", (double)n / (t1 - t0),
         (double)n / (t2 - t1));

  /* The calls above use the default lookup (pinrender render's, the least biased the library
     offers). The thesis' lookup (PINRT_THESIS_*), then the default one set by name
     (PINRT_RENDER_*): the rest of the lookup is set once per grid, the jitters go with each
     call. */
  const PinrtQueryOptions thesis = {.spatial_jitter = PINRT_THESIS_SPATIAL_JITTER,
                                    .directional_jitter = PINRT_THESIS_DIRECTIONAL_JITTER,
                                    .local_to_world = NULL};
  st = pinrt_set_lookup(grid, PINRT_THESIS_CHAIN_STRIDE, PINRT_THESIS_MIDPOINT_LOOKUP,
                        PINRT_THESIS_START_INSIDE);
  if (st != PINRT_STATUS_OK) return fail("pinrt_set_lookup", st);
  st = pinrt_set_nearest_line(grid, PINRT_THESIS_NEAREST_LINE);
  if (st != PINRT_STATUS_OK) return fail("pinrt_set_nearest_line", st);
  st = pinrt_transmittance(grid, &thesis, rays, n, seed, 0, check);
  if (st != PINRT_STATUS_OK) return fail("pinrt_transmittance (thesis lookup)", st);
  double thesis_mean = 0.0;
  for (size_t i = 0; i < n; i++) thesis_mean += check[i];
  printf("thesis lookup: mean transmittance %.6f\n", thesis_mean / (double)n);

  const PinrtQueryOptions render = {.spatial_jitter = PINRT_RENDER_SPATIAL_JITTER,
                                    .directional_jitter = PINRT_RENDER_DIRECTIONAL_JITTER,
                                    .local_to_world = NULL};
  st = pinrt_set_lookup(grid, PINRT_RENDER_CHAIN_STRIDE, PINRT_RENDER_MIDPOINT_LOOKUP,
                        PINRT_RENDER_START_INSIDE);
  if (st != PINRT_STATUS_OK) return fail("pinrt_set_lookup", st);
  st = pinrt_set_nearest_line(grid, PINRT_RENDER_NEAREST_LINE);
  if (st != PINRT_STATUS_OK) return fail("pinrt_set_nearest_line", st);
  st = pinrt_transmittance(grid, &render, rays, n, seed, 0, check);
  if (st != PINRT_STATUS_OK) return fail("pinrt_transmittance (render lookup)", st);
  double render_mean = 0.0;
  for (size_t i = 0; i < n; i++) render_mean += check[i];
  printf("render lookup: mean transmittance %.6f\n", render_mean / (double)n);

  if (argc > 4) {
    FILE *out = fopen(argv[4], "wb");
    if (!out || fwrite(rays, sizeof *rays, n, out) != n || fwrite(trans, sizeof *trans, n, out) != n ||
        fwrite(dist, sizeof *dist, n, out) != n || fclose(out) != 0) {
      fprintf(stderr, "%s: cannot write the dump\n", argv[4]);
      return 1;
    }
  }
  free(rays);
  free(trans);
  free(dist);
  free(check);
  pinrt_close(grid);
  return differ == 0 ? 0 : 1;
}
