/* Intel Embree 3 on volwarp's packet tracer benchmark scene (see README.md).
 *
 * Reads scene_M.bin written by `volwarp-embree-bench export` (spheres x,y,z,r as f32 in our
 * scene's leaf order, so primID == our sample index, and the RayBasis of each traced view),
 * builds one RTC_GEOMETRY_TYPE_SPHERE_POINT geometry (default build quality, default scene
 * flags) and traces first hits of the same primary rays (pixel centres, the direction computed
 * operation by operation like volwarp_core::RayBasis::dir; build with -ffp-contract=off) with
 * rtcIntersect1, rtcIntersect8 (4x2 packets) and rtcIntersect16 (4x4 packets), on 1 and 2
 * threads (persistent pthreads, the caller being thread 0, taking 8-row bands from an atomic
 * counter like our tracer's bands; inside a band, 8x8 tiles, packet by packet).
 *
 * usage: embree_bench SCENE.bin IDS_PREFIX MODEL [RUNS] [MODES] [THREADS]
 *   IDS_PREFIX: our tracer's ids are read from IDS_PREFIX_<res>.u32 for the hit comparison;
 *   MODES: comma list of 1,8,16 each optionally suffixed c (coherent context flag, default)
 *          or i (incoherent), e.g. "1,8,16,8i"; THREADS: comma list, default "1,2".
 * Prints one `RESULT key=value ...` line per measurement (wall clock, median of RUNS after one
 * warm-up frame), the same format as volwarp-embree-bench.
 */
#define _GNU_SOURCE
#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <xmmintrin.h>
#include <pmmintrin.h>

#define BAND_ROWS 8
#define TILE 8
#define MAX_VIEWS 4
#define MAX_THREADS 64

typedef struct {
  uint32_t w, h, our_hits, pad;
  float eye[4], corner[4], du[4], dv[4];
} View;

static double now_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

static int cmp_d(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

static double median(double *v, int n) {
  qsort(v, n, sizeof *v, cmp_d);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static void die(const char *m) {
  fprintf(stderr, "embree_bench: %s\n", m);
  exit(1);
}

static void on_error(void *user, enum RTCError code, const char *str) {
  (void)user;
  fprintf(stderr, "embree error %d: %s\n", (int)code, str ? str : "");
  exit(1);
}

/* Exactly RayBasis::dir: px = x + 0.5, d = corner + du*px + dv*py, d * (1 / sqrt(d.d)). */
static inline void ray_dir(const View *v, uint32_t x, uint32_t y, float d[3]) {
  float px = (float)x + 0.5f, py = (float)y + 0.5f;
  float dx = v->corner[0] + v->du[0] * px + v->dv[0] * py;
  float dy = v->corner[1] + v->du[1] * px + v->dv[1] * py;
  float dz = v->corner[2] + v->du[2] * px + v->dv[2] * py;
  float inv = 1.0f / sqrtf(dx * dx + dy * dy + dz * dz);
  d[0] = dx * inv;
  d[1] = dy * inv;
  d[2] = dz * inv;
}

/* ---- the frame job, shared by the threads ---- */
typedef struct {
  RTCScene scene;
  const View *view;
  uint32_t *ids;
  int mode; /* 1, 8 or 16 */
  enum RTCIntersectContextFlags flags;
  atomic_uint next_band;
  uint32_t bands;
} Job;

static Job job;
static pthread_barrier_t start_bar, end_bar;
static atomic_int quit;

/* Lane l of a packet of width pw at (x0, y0) is pixel (x0 + l % pw, y0 + l / pw). */
static void trace_band(uint32_t band) {
  const View *v = job.view;
  const uint32_t w = v->w, y_begin = band * BAND_ROWS;
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = job.flags;
  const float ox = v->eye[0], oy = v->eye[1], oz = v->eye[2];
  if (job.mode == 1) {
    for (uint32_t tx = 0; tx < w; tx += TILE)
      for (uint32_t py = 0; py < BAND_ROWS; py += 2)
        for (uint32_t px = 0; px < TILE; px += 4)
          for (uint32_t l = 0; l < 8; l++) {
            uint32_t x = tx + px + l % 4, y = y_begin + py + l / 4;
            struct RTCRayHit rh;
            float d[3];
            ray_dir(v, x, y, d);
            rh.ray.org_x = ox; rh.ray.org_y = oy; rh.ray.org_z = oz;
            rh.ray.dir_x = d[0]; rh.ray.dir_y = d[1]; rh.ray.dir_z = d[2];
            rh.ray.tnear = 0.0f; rh.ray.tfar = INFINITY; rh.ray.time = 0.0f;
            rh.ray.mask = 0xFFFFFFFFu; rh.ray.id = 0; rh.ray.flags = 0;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(job.scene, &ctx, &rh);
            job.ids[(size_t)y * w + x] = rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? 0xFFFFFFFFu : rh.hit.primID;
          }
  } else if (job.mode == 8) {
    static const int valid[8] __attribute__((aligned(32))) = {-1, -1, -1, -1, -1, -1, -1, -1};
    struct RTCRayHit8 rh __attribute__((aligned(32)));
    for (uint32_t tx = 0; tx < w; tx += TILE)
      for (uint32_t py = 0; py < BAND_ROWS; py += 2)
        for (uint32_t px = 0; px < TILE; px += 4) {
          for (uint32_t l = 0; l < 8; l++) {
            float d[3];
            ray_dir(v, tx + px + l % 4, y_begin + py + l / 4, d);
            rh.ray.org_x[l] = ox; rh.ray.org_y[l] = oy; rh.ray.org_z[l] = oz;
            rh.ray.dir_x[l] = d[0]; rh.ray.dir_y[l] = d[1]; rh.ray.dir_z[l] = d[2];
            rh.ray.tnear[l] = 0.0f; rh.ray.tfar[l] = INFINITY; rh.ray.time[l] = 0.0f;
            rh.ray.mask[l] = 0xFFFFFFFFu; rh.ray.id[l] = l; rh.ray.flags[l] = 0;
            rh.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
          }
          rtcIntersect8(valid, job.scene, &ctx, &rh);
          for (uint32_t l = 0; l < 8; l++) {
            uint32_t x = tx + px + l % 4, y = y_begin + py + l / 4;
            job.ids[(size_t)y * w + x] = rh.hit.geomID[l] == RTC_INVALID_GEOMETRY_ID ? 0xFFFFFFFFu : rh.hit.primID[l];
          }
        }
  } else {
    static const int valid[16] __attribute__((aligned(64))) = {-1, -1, -1, -1, -1, -1, -1, -1,
                                                               -1, -1, -1, -1, -1, -1, -1, -1};
    struct RTCRayHit16 rh __attribute__((aligned(64)));
    for (uint32_t tx = 0; tx < w; tx += TILE)
      for (uint32_t py = 0; py < BAND_ROWS; py += 4)
        for (uint32_t px = 0; px < TILE; px += 4) {
          for (uint32_t l = 0; l < 16; l++) {
            float d[3];
            ray_dir(v, tx + px + l % 4, y_begin + py + l / 4, d);
            rh.ray.org_x[l] = ox; rh.ray.org_y[l] = oy; rh.ray.org_z[l] = oz;
            rh.ray.dir_x[l] = d[0]; rh.ray.dir_y[l] = d[1]; rh.ray.dir_z[l] = d[2];
            rh.ray.tnear[l] = 0.0f; rh.ray.tfar[l] = INFINITY; rh.ray.time[l] = 0.0f;
            rh.ray.mask[l] = 0xFFFFFFFFu; rh.ray.id[l] = l; rh.ray.flags[l] = 0;
            rh.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
          }
          rtcIntersect16(valid, job.scene, &ctx, &rh);
          for (uint32_t l = 0; l < 16; l++) {
            uint32_t x = tx + px + l % 4, y = y_begin + py + l / 4;
            job.ids[(size_t)y * w + x] = rh.hit.geomID[l] == RTC_INVALID_GEOMETRY_ID ? 0xFFFFFFFFu : rh.hit.primID[l];
          }
        }
  }
}

static void run_bands(void) {
  for (;;) {
    uint32_t b = atomic_fetch_add(&job.next_band, 1);
    if (b >= job.bands) break;
    trace_band(b);
  }
}

static void set_ftz(void) {
  /* Embree's recommended MXCSR settings (its tutorials set them on every tracing thread). */
  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
}

static void *worker(void *arg) {
  (void)arg;
  set_ftz();
  for (;;) {
    pthread_barrier_wait(&start_bar);
    if (atomic_load(&quit)) return NULL;
    run_bands();
    pthread_barrier_wait(&end_bar);
  }
}

/* One frame on the `threads` threads (the pool was started with that many). */
static void frame(int threads) {
  atomic_store(&job.next_band, 0);
  if (threads > 1) pthread_barrier_wait(&start_bar);
  run_bands();
  if (threads > 1) pthread_barrier_wait(&end_bar);
}

static RTCScene build(RTCDevice dev, float *spheres, uint32_t n, double *ms) {
  double t0 = now_ms();
  RTCScene s = rtcNewScene(dev);
  RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_SPHERE_POINT);
  rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, spheres, 0, 16, n);
  rtcCommitGeometry(g);
  rtcAttachGeometry(s, g);
  rtcReleaseGeometry(g);
  rtcCommitScene(s);
  *ms = now_ms() - t0;
  return s;
}

int main(int argc, char **argv) {
  if (argc < 4) die("usage: embree_bench SCENE.bin IDS_PREFIX MODEL [RUNS] [MODES] [THREADS]");
  const char *scene_path = argv[1], *ids_prefix = argv[2], *model = argv[3];
  int runs = argc > 4 ? atoi(argv[4]) : 11;
  const char *modes_arg = argc > 5 ? argv[5] : "1,8,16";
  const char *threads_arg = argc > 6 ? argv[6] : "1,2";
  if (runs < 1) die("RUNS");
  set_ftz();

  FILE *f = fopen(scene_path, "rb");
  if (!f) die("cannot open the scene");
  char magic[8];
  uint32_t n, nv;
  if (fread(magic, 1, 8, f) != 8 || memcmp(magic, "VWEMB001", 8)) die("bad magic");
  if (fread(&n, 4, 1, f) != 1 || fread(&nv, 4, 1, f) != 1 || nv > MAX_VIEWS) die("bad header");
  View views[MAX_VIEWS];
  if (fread(views, sizeof(View), nv, f) != nv) die("short views");
  /* 16 spare bytes: Embree may read a full SSE vector past a buffer's last element. */
  float *spheres = aligned_alloc(64, ((size_t)n * 16 + 16 + 63) / 64 * 64);
  if (!spheres || fread(spheres, 16, n, f) != n) die("short spheres");
  fclose(f);

  printf("# Embree %s (RTC_VERSION %d), %u spheres, model %s\n", RTC_VERSION_STRING, RTC_VERSION, n, model);

  int thread_list[8], nthreads = 0;
  for (const char *p = threads_arg; *p && nthreads < 8;) {
    thread_list[nthreads++] = atoi(p);
    while (*p && *p != ',') p++;
    if (*p) p++;
  }
  double *t = malloc(sizeof(double) * runs);

  for (int ti = 0; ti < nthreads; ti++) {
    int threads = thread_list[ti];
    if (threads < 1 || threads > MAX_THREADS) die("threads");
    char cfg[256];
    /* threads=N: the size of Embree's TBB arena, used by the BVH build. */
    /* EMBREE_BENCH_CONFIG (e.g. "verbose=1") is appended to the device configuration. */
    const char *extra = getenv("EMBREE_BENCH_CONFIG");
    snprintf(cfg, sizeof cfg, "threads=%d%s%s", threads, extra ? "," : "", extra ? extra : "");
    RTCDevice dev = rtcNewDevice(cfg);
    if (!dev) die("rtcNewDevice failed");
    rtcSetDeviceErrorFunction(dev, on_error, NULL);
    if (ti == 0)
      printf("# point geometry %ld, native ray4 %ld ray8 %ld ray16 %ld, tasking system %ld (0 internal, 1 TBB, 2 PPL)\n",
             (long)rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_POINT_GEOMETRY_SUPPORTED),
             (long)rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED),
             (long)rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED),
             (long)rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED),
             (long)rtcGetDeviceProperty(dev, RTC_DEVICE_PROPERTY_TASKING_SYSTEM));

    /* Build: one warm-up, then `runs` timed builds of a fresh scene; keep the last one. */
    RTCScene scene;
    double ms;
    scene = build(dev, spheres, n, &ms);
    for (int r = 0; r < runs; r++) {
      rtcReleaseScene(scene);
      scene = build(dev, spheres, n, &t[r]);
    }
    double lo = 1e300, hi = 0;
    for (int r = 0; r < runs; r++) {
      lo = t[r] < lo ? t[r] : lo;
      hi = t[r] > hi ? t[r] : hi;
    }
    printf("RESULT tracer=embree-build model=%s res=- threads=%d what=build n=%u median_ms=%.2f min_ms=%.2f max_ms=%.2f\n",
           model, threads, n, median(t, runs), lo, hi);
    fflush(stdout);

    /* The tracing pool: threads - 1 workers besides this one. */
    pthread_t tids[MAX_THREADS];
    if (threads > 1) {
      pthread_barrier_init(&start_bar, NULL, threads);
      pthread_barrier_init(&end_bar, NULL, threads);
      atomic_store(&quit, 0);
      for (int i = 1; i < threads; i++) pthread_create(&tids[i], NULL, worker, NULL);
    }

    for (uint32_t vi = 0; vi < nv; vi++) {
      const View *v = &views[vi];
      if (v->w % TILE || v->h % BAND_ROWS) die("viewport not a multiple of 8");
      size_t np = (size_t)v->w * v->h;
      uint32_t *ids = malloc(np * 4), *ours = malloc(np * 4);
      char path[4096];
      snprintf(path, sizeof path, "%s_%u.u32", ids_prefix, v->w);
      FILE *g = fopen(path, "rb");
      int have_ours = g && fread(ours, 4, np, g) == np;
      if (g) fclose(g);
      for (const char *p = modes_arg; *p;) {
        int mode = atoi(p);
        while (*p >= '0' && *p <= '9') p++;
        enum RTCIntersectContextFlags fl = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
        if (*p == 'i') fl = RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
        while (*p && *p != ',') p++;
        if (*p) p++;
        if (mode != 1 && mode != 8 && mode != 16) die("mode");
        job.scene = scene;
        job.view = v;
        job.ids = ids;
        job.mode = mode;
        job.flags = fl;
        job.bands = v->h / BAND_ROWS;
        frame(threads); /* warm-up */
        for (int r = 0; r < runs; r++) {
          double t0 = now_ms();
          frame(threads);
          t[r] = now_ms() - t0;
        }
        lo = 1e300, hi = 0;
        for (int r = 0; r < runs; r++) {
          lo = t[r] < lo ? t[r] : lo;
          hi = t[r] > hi ? t[r] : hi;
        }
        double m = median(t, runs);
        size_t hits = 0, same = 0, only_e = 0, only_o = 0, differ = 0;
        for (size_t i = 0; i < np; i++) {
          int he = ids[i] != 0xFFFFFFFFu;
          hits += he;
          if (have_ours) {
            int ho = ours[i] != 0xFFFFFFFFu;
            if (he && ho) {
              if (ids[i] == ours[i]) same++;
              else differ++;
            } else if (he) only_e++;
            else if (ho) only_o++;
          }
        }
        printf("RESULT tracer=embree-%d%s model=%s res=%u threads=%d what=trace n=%u median_ms=%.3f min_ms=%.3f max_ms=%.3f fps=%.1f mrays=%.2f hits=%zu our_hits=%u same_prim=%zu other_prim=%zu only_embree=%zu only_ours=%zu\n",
               mode, fl == RTC_INTERSECT_CONTEXT_FLAG_COHERENT ? "c" : "i", model, v->w, threads, n, m, lo, hi,
               1e3 / m, (double)np / m / 1e3, hits, v->our_hits, same, differ, only_e, only_o);
        fflush(stdout);
      }
      free(ids);
      free(ours);
    }
    if (threads > 1) {
      atomic_store(&quit, 1);
      pthread_barrier_wait(&start_bar);
      for (int i = 1; i < threads; i++) pthread_join(tids[i], NULL);
      pthread_barrier_destroy(&start_bar);
      pthread_barrier_destroy(&end_bar);
    }
    rtcReleaseScene(scene);
    rtcReleaseDevice(dev);
  }
  free(t);
  free(spheres);
  return 0;
}
