/*
 * Embree 3 (Debian's libembree-dev) on the meshes and rays that `oxray bench --export DIR`
 * writes: build time at MEDIUM quality and ray throughput with rtcIntersect1 / rtcOccluded1
 * called from a parallel loop of POSIX threads, for a side-by-side comparison with oxray.
 *
 *   cc -O2 -o embree3_bench scripts/embree3_bench.c -lembree3 -lpthread
 *   embree3_bench DIR NAME... [--threads 1,2] [--runs 5] [--builds 5] [--scene-flags robust|none]
 *                 [--packet 8] [--quality low|medium|high]
 *
 * Input (all little endian), for each NAME (the files `oxray bench --export` writes):
 *   NAME.mesh                u32 vertex count, u32 triangle count, f32x3 vertices, u32x3 triangles
 *   NAME.{coherent,incoherent,shadow}.rays
 *                            f32[8] per ray: ox oy oz tmin dx dy dz tmax (tmax may be +inf)
 *   NAME.{coherent,incoherent}.oxray-hits   (optional) f32 t per ray, +inf for a miss
 *   NAME.{coherent,incoherent}.oxray-prims  (optional) u32 primitive index, 0xffffffff for a miss
 *   NAME.{coherent,incoherent,shadow}.oxray-occluded (optional) u8 per ray, 1 when blocked
 * When oxray's files are there, Embree's answers are compared with them ray by ray.
 *
 * Unlike embreex (scripts/bench_embree.py), Embree 3's ray takes tnear, so rays are traced
 * exactly as oxray traces them (tmin honoured, origins unchanged).
 *
 * Output: one line per measurement, `RESULT key=value ...`, for scripts/bench_table.py, and
 * the agreement with oxray as `AGREE ...` lines; anything else is commentary.
 *
 * Threads: each timed call runs T POSIX threads that take chunks of 256 rays from a shared
 * counter (as oxray's rayon loop takes chunks of 256), each ray with its own rtcIntersect1 or
 * rtcOccluded1 call. The BVH build runs on Embree's own (TBB) threads, limited to T with the
 * device configuration "threads=T"; one device per thread count. With --packet 8, each thread
 * traces its chunk in groups of eight consecutive rays with rtcIntersect8 / rtcOccluded8 (a
 * packet of SIMD lanes, one ray a lane), as a renderer that keeps its paths in lanes would.
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

#define CHUNK 256
#define NO_PRIM 0xffffffffu

/* Rays per rtcIntersect call: 1, or 8 with --packet 8. */
static int packet = 1;

/* The scene's build quality (--quality; MEDIUM by default, HIGH is what Mitsuba 3 asks for:
 * spatial splits). */
static enum RTCBuildQuality quality = RTC_BUILD_QUALITY_MEDIUM;

static void die(const char *msg, const char *arg) {
    fprintf(stderr, "embree3_bench: error: %s%s%s\n", msg, arg ? ": " : "", arg ? arg : "");
    exit(1);
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int cmp_double(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The median of n values (sorts them). */
static double median(double *xs, int n) {
    qsort(xs, n, sizeof(double), cmp_double);
    return n % 2 ? xs[n / 2] : 0.5 * (xs[n / 2 - 1] + xs[n / 2]);
}

/* Reads a whole file; NULL (and *len = 0) when it does not exist. */
static void *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    *len = 0;
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) != 0) die("cannot seek", path);
    long n = ftell(f);
    if (n < 0) die("cannot size", path);
    rewind(f);
    void *buf = malloc(n > 0 ? (size_t)n : 1);
    if (!buf) die("out of memory reading", path);
    if (n > 0 && fread(buf, 1, (size_t)n, f) != (size_t)n) die("cannot read", path);
    fclose(f);
    *len = (size_t)n;
    return buf;
}

typedef struct {
    float o[3], tmin, d[3], tmax;
} RayRec;

typedef struct {
    const char *name;
    RayRec *rays;
    size_t n;
} RaySet;

/* What one parallel call does. */
typedef struct {
    RTCScene scene;
    const RayRec *rays;
    size_t n;
    int occluded;      /* rtcOccluded1 instead of rtcIntersect1 */
    float *t;          /* closest: hit distance (+inf for a miss); may be NULL */
    uint32_t *prim;    /* closest: primitive (NO_PRIM for a miss); may be NULL */
    uint8_t *blocked;  /* occluded: 1 when blocked; may be NULL */
    atomic_size_t next;
} Job;

/* Rays start..end of the job in groups of eight (the last group masked). */
static void trace8(Job *job, struct RTCIntersectContext *ctx, size_t start, size_t end) {
    for (size_t g = start; g < end; g += 8) {
        int valid[8];
        struct RTCRayHit8 rh;
        for (int l = 0; l < 8; l++) {
            size_t i = g + l;
            valid[l] = i < end ? -1 : 0;
            const RayRec *r = &job->rays[i < end ? i : start];
            rh.ray.org_x[l] = r->o[0]; rh.ray.org_y[l] = r->o[1]; rh.ray.org_z[l] = r->o[2];
            rh.ray.dir_x[l] = r->d[0]; rh.ray.dir_y[l] = r->d[1]; rh.ray.dir_z[l] = r->d[2];
            rh.ray.tnear[l] = r->tmin; rh.ray.tfar[l] = r->tmax;
            rh.ray.time[l] = 0.0f; rh.ray.mask[l] = 0xffffffffu; rh.ray.id[l] = 0;
            rh.ray.flags[l] = 0;
            rh.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
        }
        if (job->occluded) {
            rtcOccluded8(valid, job->scene, ctx, &rh.ray);
        } else {
            rtcIntersect8(valid, job->scene, ctx, &rh);
        }
        for (int l = 0; l < 8 && g + l < end; l++) {
            size_t i = g + l;
            if (job->occluded) {
                if (job->blocked) job->blocked[i] = rh.ray.tfar[l] < 0.0f;
            } else {
                int hit = rh.hit.geomID[l] != RTC_INVALID_GEOMETRY_ID;
                if (job->t) job->t[i] = hit ? rh.ray.tfar[l] : INFINITY;
                if (job->prim) job->prim[i] = hit ? rh.hit.primID[l] : NO_PRIM;
            }
        }
    }
}

static void *worker(void *arg) {
    Job *job = arg;
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    for (;;) {
        size_t start = atomic_fetch_add_explicit(&job->next, CHUNK, memory_order_relaxed);
        if (start >= job->n) break;
        size_t end = start + CHUNK < job->n ? start + CHUNK : job->n;
        if (packet == 8) {
            trace8(job, &ctx, start, end);
            continue;
        }
        for (size_t i = start; i < end; i++) {
            const RayRec *r = &job->rays[i];
            if (job->occluded) {
                struct RTCRay ray;
                ray.org_x = r->o[0]; ray.org_y = r->o[1]; ray.org_z = r->o[2];
                ray.dir_x = r->d[0]; ray.dir_y = r->d[1]; ray.dir_z = r->d[2];
                ray.tnear = r->tmin; ray.tfar = r->tmax;
                ray.time = 0.0f; ray.mask = 0xffffffffu; ray.id = 0; ray.flags = 0;
                rtcOccluded1(job->scene, &ctx, &ray);
                /* Embree sets tfar to -inf for an occluded ray. */
                if (job->blocked) job->blocked[i] = ray.tfar < 0.0f;
            } else {
                struct RTCRayHit rh;
                rh.ray.org_x = r->o[0]; rh.ray.org_y = r->o[1]; rh.ray.org_z = r->o[2];
                rh.ray.dir_x = r->d[0]; rh.ray.dir_y = r->d[1]; rh.ray.dir_z = r->d[2];
                rh.ray.tnear = r->tmin; rh.ray.tfar = r->tmax;
                rh.ray.time = 0.0f; rh.ray.mask = 0xffffffffu; rh.ray.id = 0; rh.ray.flags = 0;
                rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
                rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
                rtcIntersect1(job->scene, &ctx, &rh);
                int hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
                if (job->t) job->t[i] = hit ? rh.ray.tfar : INFINITY;
                if (job->prim) job->prim[i] = hit ? rh.hit.primID : NO_PRIM;
            }
        }
    }
    return NULL;
}

/* Traces a whole set on `threads` threads; returns the wall time in seconds. */
static double trace(Job *job, int threads) {
    pthread_t tid[256];
    atomic_store(&job->next, 0);
    double t0 = now();
    for (int k = 1; k < threads; k++)
        if (pthread_create(&tid[k], NULL, worker, job) != 0) die("cannot start a thread", NULL);
    worker(job); /* the calling thread is thread 0 */
    for (int k = 1; k < threads; k++) pthread_join(tid[k], NULL);
    return now() - t0;
}

static void on_error(void *user, enum RTCError code, const char *str) {
    (void)user;
    fprintf(stderr, "embree3_bench: Embree error %d: %s\n", (int)code, str ? str : "");
    exit(1);
}

typedef struct {
    uint32_t nv, nt;
    const float *v;
    const uint32_t *tri;
} Mesh;

/* A committed scene over the mesh; *build_s gets rtcCommitScene's wall time. */
static RTCScene make_scene(RTCDevice dev, const Mesh *m, int robust, double *build_s) {
    RTCScene scene = rtcNewScene(dev);
    rtcSetSceneFlags(scene, robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
    rtcSetSceneBuildQuality(scene, quality);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(g, quality);
    /* Embree's own buffers (padded and aligned as it requires); the copy is not timed. */
    float *v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                       3 * sizeof(float), m->nv);
    uint32_t *t = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                          3 * sizeof(uint32_t), m->nt);
    memcpy(v, m->v, (size_t)m->nv * 12);
    memcpy(t, m->tri, (size_t)m->nt * 12);
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    double t0 = now();
    rtcCommitScene(scene);
    *build_s = now() - t0;
    return scene;
}

/* Compares closest hits with oxray's: same hit or miss, t within `tol` (relative), same
 * primitive unless both hit within `tol` of each other (a tie: a shared edge or vertex). */
static void agree_closest(const char *mesh, const char *set, size_t n, const float *t,
                          const uint32_t *prim, const char *dir) {
    char path[4096];
    size_t lt, lp;
    snprintf(path, sizeof path, "%s/%s.%s.oxray-hits", dir, mesh, set);
    float *ot = read_file(path, &lt);
    snprintf(path, sizeof path, "%s/%s.%s.oxray-prims", dir, mesh, set);
    uint32_t *op = read_file(path, &lp);
    if (!ot || lt != n * 4) {
        printf("AGREE mesh=%s set=%s query=closest status=no-oxray-hits\n", mesh, set);
        free(ot); free(op);
        return;
    }
    if (op && lp != n * 4) { free(op); op = NULL; }
    const double tol = 1e-5;
    size_t hitmiss = 0, tdiff = 0, ties = 0, primdiff = 0, hits = 0;
    double worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        int he = isfinite(t[i]), ho = isfinite(ot[i]);
        if (he != ho) { hitmiss++; continue; }
        if (!he) continue;
        hits++;
        double a = t[i], b = ot[i];
        double rel = fabs(a - b) / fmax(fabs(a), fabs(b));
        if (rel > worst) worst = rel;
        int same_t = rel <= tol;
        if (!same_t) tdiff++;
        if (op && op[i] != prim[i]) {
            if (same_t) ties++; else primdiff++;
        }
    }
    printf("AGREE mesh=%s set=%s query=closest rays=%zu hits=%zu hit_miss_differ=%zu "
           "t_differ=%zu prim_differ=%zu prim_ties=%zu worst_rel_t=%.3g tol=%.0e%s\n",
           mesh, set, n, hits, hitmiss, tdiff, primdiff, ties, worst, tol,
           op ? "" : " prims=absent");
    free(ot); free(op);
}

static void agree_occluded(const char *mesh, const char *set, size_t n, const uint8_t *b,
                           const char *dir) {
    char path[4096];
    size_t len;
    snprintf(path, sizeof path, "%s/%s.%s.oxray-occluded", dir, mesh, set);
    uint8_t *ob = read_file(path, &len);
    if (!ob || len != n) {
        printf("AGREE mesh=%s set=%s query=any status=no-oxray-occluded\n", mesh, set);
        free(ob);
        return;
    }
    size_t differ = 0, blocked = 0;
    for (size_t i = 0; i < n; i++) {
        differ += (ob[i] != 0) != (b[i] != 0);
        blocked += b[i] != 0;
    }
    printf("AGREE mesh=%s set=%s query=any rays=%zu blocked=%zu differ=%zu\n", mesh, set, n,
           blocked, differ);
    free(ob);
}

static void usage(void) {
    fprintf(stderr,
            "usage: embree3_bench DIR NAME... [--threads 1,2] [--runs 5] [--builds 5] "
            "[--scene-flags robust|none] [--packet 8] [--quality low|medium|high]\n");
    exit(2);
}

int main(int argc, char **argv) {
    const char *dir = NULL;
    const char *names[64];
    int nnames = 0, runs = 5, builds = 5, robust = 1;
    int threads[16], nthreads = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--runs") && i + 1 < argc) runs = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--builds") && i + 1 < argc) builds = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--packet") && i + 1 < argc) {
            packet = atoi(argv[++i]);
            if (packet != 1 && packet != 8) usage();
        }
        else if (!strcmp(argv[i], "--quality") && i + 1 < argc) {
            const char *q = argv[++i];
            if (!strcmp(q, "low")) quality = RTC_BUILD_QUALITY_LOW;
            else if (!strcmp(q, "medium")) quality = RTC_BUILD_QUALITY_MEDIUM;
            else if (!strcmp(q, "high")) quality = RTC_BUILD_QUALITY_HIGH;
            else usage();
        }
        else if (!strcmp(argv[i], "--scene-flags") && i + 1 < argc) {
            const char *f = argv[++i];
            if (!strcmp(f, "robust")) robust = 1;
            else if (!strcmp(f, "none")) robust = 0;
            else usage();
        } else if (!strcmp(argv[i], "--threads") && i + 1 < argc) {
            char *s = argv[++i], *end;
            while (*s && nthreads < 16) {
                long t = strtol(s, &end, 10);
                if (end == s || t < 1 || t > 256) usage();
                threads[nthreads++] = (int)t;
                s = *end == ',' ? end + 1 : end;
            }
        } else if (argv[i][0] == '-') usage();
        else if (!dir) dir = argv[i];
        else if (nnames < 64) names[nnames++] = argv[i];
    }
    if (!dir || nnames == 0 || runs < 1 || builds < 1) usage();
    if (nthreads == 0) threads[nthreads++] = 1;

    printf("Embree %d.%d.%d (libembree3), scene flags %s, build quality MEDIUM, "
           "median of %d builds and %d runs after a warm-up, %d ray(s) a call\n",
           RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH,
           robust ? "ROBUST" : "NONE", builds, runs, packet);
    for (int m = 0; m < nnames; m++) {
        char path[4096];
        size_t len;
        snprintf(path, sizeof path, "%s/%s.mesh", dir, names[m]);
        uint8_t *raw = read_file(path, &len);
        if (!raw || len < 8) die("cannot read the mesh", path);
        Mesh mesh;
        memcpy(&mesh.nv, raw, 4);
        memcpy(&mesh.nt, raw + 4, 4);
        if (len != 8 + 12 * (size_t)mesh.nv + 12 * (size_t)mesh.nt) die("bad mesh size", path);
        mesh.v = (const float *)(raw + 8);
        mesh.tri = (const uint32_t *)(raw + 8 + 12 * (size_t)mesh.nv);
        for (size_t i = 0; i < 3 * (size_t)mesh.nt; i++)
            if (mesh.tri[i] >= mesh.nv) die("vertex index out of range", path);

        static const char *set_names[3] = {"coherent", "incoherent", "shadow"};
        RaySet sets[3];
        for (int s = 0; s < 3; s++) {
            snprintf(path, sizeof path, "%s/%s.%s.rays", dir, names[m], set_names[s]);
            sets[s].name = set_names[s];
            sets[s].rays = read_file(path, &len);
            if (len % sizeof(RayRec)) die("ray file size is not a multiple of 32", path);
            sets[s].n = len / sizeof(RayRec);
        }

        for (int k = 0; k < nthreads; k++) {
            int T = threads[k];
            char config[64];
            snprintf(config, sizeof config, "threads=%d", T);
            RTCDevice dev = rtcNewDevice(config);
            if (!dev) die("rtcNewDevice failed", config);
            rtcSetDeviceErrorFunction(dev, on_error, NULL);
            double *bt = calloc(builds, sizeof(double));
            RTCScene scene = NULL;
            for (int b = 0; b < builds; b++) {
                if (scene) rtcReleaseScene(scene);
                scene = make_scene(dev, &mesh, robust, &bt[b]);
            }
            printf("RESULT engine=embree3 mesh=%s tris=%u threads=%d metric=build_ms value=%.3f\n",
                   names[m], mesh.nt, T, median(bt, builds) * 1e3);
            free(bt);
            double *tt = calloc(runs, sizeof(double));
            for (int s = 0; s < 3; s++) {
                RaySet *rs = &sets[s];
                if (!rs->rays || rs->n == 0) continue;
                for (int occ = 0; occ < 2; occ++) {
                    if (!occ && s == 2) continue; /* shadow rays: any hit only */
                    Job job = {.scene = scene, .rays = rs->rays, .n = rs->n, .occluded = occ};
                    trace(&job, T); /* warm-up */
                    for (int r = 0; r < runs; r++) tt[r] = trace(&job, T);
                    printf("RESULT engine=embree3 mesh=%s tris=%u threads=%d metric=%s_%s "
                           "value=%.4f\n",
                           names[m], mesh.nt, T, rs->name, occ ? "any" : "closest",
                           rs->n / median(tt, runs) / 1e6);
                    fflush(stdout);
                    if (k == 0) {
                        /* Answers once (they do not depend on the thread count). */
                        float *t = occ ? NULL : malloc(rs->n * 4);
                        uint32_t *p = occ ? NULL : malloc(rs->n * 4);
                        uint8_t *bl = occ ? malloc(rs->n) : NULL;
                        Job check = {.scene = scene, .rays = rs->rays, .n = rs->n,
                                     .occluded = occ, .t = t, .prim = p, .blocked = bl};
                        trace(&check, T);
                        if (occ) agree_occluded(names[m], rs->name, rs->n, bl, dir);
                        else agree_closest(names[m], rs->name, rs->n, t, p, dir);
                        free(t); free(p); free(bl);
                    }
                }
            }
            free(tt);
            rtcReleaseScene(scene);
            rtcReleaseDevice(dev);
        }
        for (int s = 0; s < 3; s++) free(sets[s].rays);
        free(raw);
    }
    return 0;
}
