#include "pmsm/hal/signals.hpp"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <cerrno>

namespace pmsm::hal {
namespace {

std::atomic<bool> g_stop{false};
static_assert(std::atomic<bool>::is_always_lock_free);
int g_pipe[2] = {-1, -1};
bool g_installed = false;

extern "C" void on_stop_signal(int /*signal*/) {
  const int saved = errno;
  g_stop.store(true, std::memory_order_relaxed);
  if (g_pipe[1] >= 0) {
    const char byte = 1;
    [[maybe_unused]] const ssize_t n = ::write(g_pipe[1], &byte, 1);  // non-blocking; a full pipe is fine
  }
  errno = saved;
}

}  // namespace

Status install_stop_signals() {
  if (g_installed) {
    return {};
  }
  if (::pipe2(g_pipe, O_NONBLOCK | O_CLOEXEC) != 0) {
    const int e = errno;
    return Status::error(e, "cannot create the stop-signal pipe: " + errno_text(e));
  }
  struct sigaction action {};
  action.sa_handler = on_stop_signal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = 0;  // no SA_RESTART: a blocked wait returns early (it re-checks anyway)
  // SIGHUP too: by default it kills the process at once (a daemon started from a terminal that
  // closes), without the clean stop's last word to the power stage and its stored state.
  if (::sigaction(SIGINT, &action, nullptr) != 0 || ::sigaction(SIGTERM, &action, nullptr) != 0 ||
      ::sigaction(SIGHUP, &action, nullptr) != 0) {
    const int e = errno;
    return Status::error(e, "cannot install the SIGINT/SIGTERM/SIGHUP handlers: " + errno_text(e));
  }
  g_installed = true;
  return {};
}

std::atomic<bool>& stop_requested() noexcept { return g_stop; }

int stop_signal_fd() noexcept { return g_pipe[0]; }

}  // namespace pmsm::hal
