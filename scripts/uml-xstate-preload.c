/* uml-xstate-preload: an LD_PRELOAD library for Debian 12's User-Mode Linux kernel (6.1)
 * on hosts whose XSAVE area is larger than the one that kernel was built for.
 *
 * UML saves and restores each guest process's floating-point state through ptrace
 * (PTRACE_GETREGSET / PTRACE_SETREGSET, NT_X86_XSTATE) with a buffer of its own fixed size:
 * 2,696 bytes in Debian's build (x87, SSE, AVX, AVX-512, PKRU). The host kernel hands out
 * at most its own size on a read, but accepts a write only of exactly its whole XSAVE area
 * (arch/x86/kernel/fpu/regset.c, xstateregs_set: count != fpu_user_cfg.max_size -> EFAULT).
 * On a host with AMX (11,008 bytes) every write is refused, UML reports "ptrace set fp regs
 * failed, errno = 14" and the guest's first process dies before it runs.
 *
 * This library stands between UML and the host for exactly those two requests:
 * - read: the host's whole area is read and the first iov_len bytes (UML's size) are handed
 *   to UML, which is what the host would return for a short buffer anyway;
 * - write: the host's whole area is read, UML's bytes are laid over its head (standard,
 *   non-compacted format: every component UML knows sits at the same offset in both, and
 *   the header's xstate_bv is UML's) and the whole area is written back. The host puts every
 *   component whose xstate_bv bit is clear in its initial state.
 * A component that lies beyond UML's buffer (AMX tile state) cannot be carried: a read whose
 * xstate_bv marks one in use, or a write whose xstate_bv asks for one, fails with EFAULT, as
 * the host itself would have failed, never silently. No guest process can use AMX (UML does
 * not pass the permission request, ARCH_REQ_XCOMP_PERM, to the host), so neither happens today.
 * The first request reads the host's area once to learn its size; where that fits UML's
 * buffer, every request after it passes through unchanged. Nothing else is touched. Built and
 * used by scripts/uml-run. (Like UML's own requests, these assume a valid iov_base and an
 * iov_len the host accepts; UML passes nothing else.) */
#define _GNU_SOURCE
#include <cpuid.h>
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>

typedef long (*ptrace_fn)(enum __ptrace_request, ...);

/* The host's whole XSAVE area; 64 KiB is well above any x86 CPU's (11,008 bytes with AMX).
 * UML calls ptrace from one thread only. */
static _Alignas(64) unsigned char host_area[64 * 1024];

/* Where each component of the standard format ends (CPUID leaf 0xD, sub-leaf i: the size in
 * EAX, the offset in EBX), read once: CPUID is a trap to the hypervisor in a virtual machine.
 * Components 0 and 1 are in the legacy area; one CPUID does not name lies beyond any size. */
static size_t component_end[64];

static void read_component_ends(void) {
  for (unsigned i = 2; i < 64; ++i) {
    unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
    component_end[i] = __get_cpuid_count(0xD, i, &eax, &ebx, &ecx, &edx) && eax != 0
                           ? (size_t)ebx + eax
                           : (size_t)-1; /* unknown: never within any size */
  }
}

/* Whether every component that the header of this standard-format area marks lies within its
 * first size bytes. */
static int components_within(const unsigned char *area, size_t size) {
  enum { kHeaderOffset = 512 };
  if (size < kHeaderOffset + sizeof(uint64_t)) {
    return 0;
  }
  uint64_t xstate_bv;
  memcpy(&xstate_bv, area + kHeaderOffset, sizeof xstate_bv);
  for (unsigned i = 2; i < 64; ++i) {
    if (((xstate_bv >> i) & 1U) && component_end[i] > size) {
      return 0;
    }
  }
  return 1;
}

long ptrace(enum __ptrace_request request, ...) {
  va_list ap;
  va_start(ap, request);
  pid_t pid = va_arg(ap, pid_t);
  void *addr = va_arg(ap, void *);
  void *data = va_arg(ap, void *);
  va_end(ap);

  static ptrace_fn real_ptrace;
  if (real_ptrace == NULL) {
    real_ptrace = (ptrace_fn)dlsym(RTLD_NEXT, "ptrace");
    if (real_ptrace == NULL) {
      errno = ENOSYS;
      return -1;
    }
  }
  if ((request != PTRACE_GETREGSET && request != PTRACE_SETREGSET) ||
      (unsigned long)addr != NT_X86_XSTATE || data == NULL) {
    return real_ptrace(request, pid, addr, data);
  }

  /* 0 until the first request tells how large the host's area is. */
  static size_t host_size;
  struct iovec *caller = data;
  if (host_size != 0 && host_size <= caller->iov_len) {
    return real_ptrace(request, pid, addr, data);
  }
  struct iovec whole = {host_area, sizeof host_area};
  if (real_ptrace(PTRACE_GETREGSET, pid, addr, &whole) != 0) {
    return -1;
  }
  if (host_size == 0) {
    read_component_ends();
  }
  host_size = whole.iov_len;
  if (host_size <= caller->iov_len) {
    return real_ptrace(request, pid, addr, data);
  }
  const unsigned char *marked = request == PTRACE_GETREGSET ? host_area : caller->iov_base;
  if (!components_within(marked, caller->iov_len)) {
    fprintf(stderr, "uml-xstate-preload: %s of process %d: its XSAVE header marks a component beyond "
            "the %zu bytes the UML kernel carries (host area %zu bytes): refused (EFAULT)\n",
            request == PTRACE_GETREGSET ? "read" : "write", (int)pid, caller->iov_len, host_size);
    errno = EFAULT;
    return -1;
  }
  if (request == PTRACE_GETREGSET) {
    memcpy(caller->iov_base, host_area, caller->iov_len);
    return 0;
  }
  memcpy(host_area, caller->iov_base, caller->iov_len);
  const long written = real_ptrace(PTRACE_SETREGSET, pid, addr, &whole);
  if (written != 0) {
    const int saved = errno;
    fprintf(stderr, "uml-xstate-preload: write of process %d's XSAVE area (%zu bytes, UML's %zu) failed: %s\n",
            (int)pid, host_size, caller->iov_len, strerror(saved));
    errno = saved;
  }
  return written;
}
