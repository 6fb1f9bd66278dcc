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
 *   the header's xstate_bv is UML's) and the whole area is written back. The components
 *   UML does not know (AMX tile state, which no guest process may use without asking the
 *   host for permission) keep the host's values.
 * Where the host's area is no larger than UML's buffer, every request passes through
 * unchanged. Nothing else is touched. Built and used by scripts/uml-run. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <stdarg.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>

typedef long (*ptrace_fn)(enum __ptrace_request, ...);

/* The host's whole XSAVE area; 64 KiB is well above any x86 CPU's (11,008 bytes with AMX).
 * UML calls ptrace from one thread only. */
static _Alignas(64) unsigned char host_area[64 * 1024];

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
  host_size = whole.iov_len;
  if (host_size <= caller->iov_len) {
    return real_ptrace(request, pid, addr, data);
  }
  if (request == PTRACE_GETREGSET) {
    memcpy(caller->iov_base, host_area, caller->iov_len);
    return 0;
  }
  memcpy(host_area, caller->iov_base, caller->iov_len);
  return real_ptrace(PTRACE_SETREGSET, pid, addr, &whole);
}
