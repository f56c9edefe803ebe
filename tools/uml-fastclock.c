/*
 * uml-fastclock: gettimeofday(2) without a system call, preloaded into the vcan-run guest.
 *
 * User-mode Linux has no vDSO: every time call of a guest process is a system call, which UML
 * turns into a ptrace round trip through the host (about 0.1 ms on our development VM). PyBullet
 * reads gettimeofday(2) several times per API call and per physics step for its profiling timers,
 * so inside the guest the simulation ran 6-10 times slower than on the host, slower than real
 * time (measured with strace -c: 85 gettimeofday calls per 20 ms tick, and `aider-exo bench
 * nodes` in the guest: 15-20 ms of simulation per tick without this library, 2.4-2.9 ms with it).
 *
 * This library answers gettimeofday from the CPU's time-stamp counter, anchored on the kernel's
 * CLOCK_REALTIME: the first call anchors, a call at least 10 ms later measures the slope and
 * anchors again. A slope measured over a span is trusted for at most 4 such spans (and at most a
 * second) before the next call asks the kernel and re-measures it over the longer span, so the
 * error stays within a few times the jitter of one kernel call (0.1 ms in the guest) at the start
 * and near it later, and the span grows 10, 40, 160, 640 ms, then a second. Calls that ask for the time zone,
 * and any call whose counter went backwards, go to the kernel. State is per thread, so threads
 * never race. Only gettimeofday is replaced: clock_gettime, and every sleep and timer, stay the
 * kernel's, so the real-time loops measured in the guest run on the real clock.
 *
 * vcan-run builds it only on x86-64 with an invariant TSC (constant_tsc and nonstop_tsc).
 */
#define _GNU_SOURCE
#include <stdint.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>
#include <x86intrin.h>

#define CALIBRATE_NS 10000000LL /* the first slope after 10 ms */
#define TRUST_SPANS 4            /* a slope is used for at most 4 times the span it was measured on */
#define HORIZON_MAX_NS 1000000000LL

static __thread uint64_t tsc_anchor; /* 0: no anchor yet */
static __thread int64_t ns_anchor;
static __thread double ns_per_tsc; /* 0: no slope yet */
static __thread int64_t horizon_ns; /* how long after the anchor the slope is used */

static int64_t kernel_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static int64_t now_ns(void)
{
    uint64_t tsc = __rdtsc();
    if (ns_per_tsc > 0.0 && tsc >= tsc_anchor) {
        int64_t since = (int64_t)((double)(tsc - tsc_anchor) * ns_per_tsc);
        if (since < horizon_ns)
            return ns_anchor + since;
    }
    int64_t ns = kernel_ns();
    int64_t span = ns - ns_anchor;
    if (tsc_anchor != 0 && span >= CALIBRATE_NS) {
        if (tsc > tsc_anchor) {
            ns_per_tsc = (double)span / (double)(tsc - tsc_anchor);
            horizon_ns = span < HORIZON_MAX_NS / TRUST_SPANS ? TRUST_SPANS * span : HORIZON_MAX_NS;
        } else {
            ns_per_tsc = 0.0; /* the counter went backwards: measure the slope again */
        }
    }
    if (tsc_anchor == 0 || span >= CALIBRATE_NS) {
        tsc_anchor = tsc;
        ns_anchor = ns;
    }
    return ns;
}

#pragma GCC diagnostic ignored "-Wnonnull-compare"
int gettimeofday(struct timeval *restrict tv, void *restrict tz)
{
    if (tz != NULL)
        return (int)syscall(SYS_gettimeofday, tv, tz);
    if (tv != NULL) { /* glibc declares it nonnull, yet the kernel accepts NULL */
        int64_t ns = now_ns();
        tv->tv_sec = (time_t)(ns / 1000000000LL);
        tv->tv_usec = (suseconds_t)((ns % 1000000000LL) / 1000);
    }
    return 0;
}
