// SIGINT / SIGTERM / SIGHUP as a stop request that both a flag and a descriptor wait can see.
//
// install_stop_signals() installs an async-signal-safe handler (no SA_RESTART, so a blocked
// wait returns early with EINTR) that sets a lock-free flag and writes one byte to a
// self-pipe; a loop waiting with DescriptorWait adds stop_signal_fd() and wakes at once.
// A second signal while the first is being handled changes nothing: stopping is
// idempotent.
#pragma once

#include <atomic>

#include "pmsm/hal/status.hpp"

namespace pmsm::hal {

// Installs the handlers (once per process; later calls return the same state).
[[nodiscard]] Status install_stop_signals();
// The flag set by the handler (also usable as a plain stop flag by tests).
[[nodiscard]] std::atomic<bool>& stop_requested() noexcept;
// Readable once a stop signal arrived (-1 before install_stop_signals()).
[[nodiscard]] int stop_signal_fd() noexcept;

}  // namespace pmsm::hal
