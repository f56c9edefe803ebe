/* uml-xstate: lets Debian bookworm's user-mode Linux (6.1) run on hosts with
 * AMX (Intel Sapphire Rapids and later), whose XSAVE area UML writes short.
 *
 * Preloaded into the UML kernel binary on the host by tools/vcan-run
 * (LD_PRELOAD), never into anything else.
 *
 * The problem: UML saves and restores each guest thread's FPU state with
 * ptrace(PTRACE_GETREGSET / PTRACE_SETREGSET, NT_X86_XSTATE) and a buffer the
 * size of the host's XSAVE area without its dynamic features (measured on an
 * AVX-512 + AMX host: 2696 bytes, x87 to AVX-512). Reading a short buffer is
 * allowed (the host kernel truncates), but writing needs the whole
 * standard-format area, dynamic features included (Linux 5.14 and later,
 * xstateregs_set(): "count != fpu_user_cfg.max_size -> -EFAULT"; here 11008
 * bytes). Every restore fails and the guest's init dies at once with
 * "ptrace set fp regs failed, errno = 14".
 *
 * The fix, in ptrace() as UML calls it: a SETREGSET of NT_X86_XSTATE that is
 * shorter than the host's area is written as the whole area, UML's bytes then
 * zeros. What lies past UML's bytes is only dynamic state (AMX tile
 * configuration and data), which no guest thread can have in use: it needs
 * arch_prctl(ARCH_REQ_XCOMP_PERM) on the host, which UML's processes never
 * ask for. The XSAVE header UML passes (xstate_bv) marks it unused, so the
 * zeros are read as its init state and nothing UML knows of changes (AVX-512
 * registers kept across preemption: checked by tests/bus/test_vcan_run.py).
 * Every other ptrace call passes through unchanged.
 *
 * Build: cc -O2 -shared -fPIC -o uml-xstate.so uml-xstate.c -ldl
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <stdint.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>

#ifndef NT_X86_XSTATE
#define NT_X86_XSTATE 0x202
#endif

#define AREA_MAX (64 * 1024) /* larger than any XSAVE area (AMX: about 11 KiB) */

typedef long (*ptrace_fn)(enum __ptrace_request, ...); /* glibc's, variadic */

static ptrace_fn real_ptrace;
static size_t area_size; /* the host's whole XSAVE area, once a short write failed */
static unsigned char area[AREA_MAX] __attribute__((aligned(64)));

static long set_xstate(pid_t pid, struct iovec *uml)
{
    if (area_size == 0 || uml->iov_len >= area_size) {
        long rc = real_ptrace(PTRACE_SETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, uml);
        if (rc == 0 || errno != EFAULT || area_size != 0)
            return rc;
        /* The first short write: learn the area's size from a whole read. */
        struct iovec probe = {area, AREA_MAX};
        if (real_ptrace(PTRACE_GETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, &probe) < 0
            || probe.iov_len <= uml->iov_len) {
            errno = EFAULT;
            return -1;
        }
        area_size = probe.iov_len;
    }
    memcpy(area, uml->iov_base, uml->iov_len);
    memset(area + uml->iov_len, 0, area_size - uml->iov_len);
    struct iovec whole = {area, area_size};
    return real_ptrace(PTRACE_SETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, &whole);
}

long ptrace(enum __ptrace_request request, ...)
{
    __builtin_va_list ap;
    __builtin_va_start(ap, request);
    pid_t pid = __builtin_va_arg(ap, pid_t);
    void *addr = __builtin_va_arg(ap, void *);
    void *data = __builtin_va_arg(ap, void *);
    __builtin_va_end(ap);
    if (real_ptrace == NULL)
        real_ptrace = (ptrace_fn)dlsym(RTLD_NEXT, "ptrace");
    if (request == PTRACE_SETREGSET && (uintptr_t)addr == NT_X86_XSTATE && data != NULL)
        return set_xstate(pid, data);
    return real_ptrace(request, pid, addr, data);
}
