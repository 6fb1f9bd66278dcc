// Null and simulated GPIO backends, and the choice between null and libgpiod.
#include "pmsm/hal/gpio.hpp"

#include <sys/eventfd.h>
#include <unistd.h>

#include <cstdint>

namespace pmsm::hal {

bool NullGateEnableOutput::set_active(bool active) noexcept {
  active_ = active;
  return true;
}

bool SimGateEnableOutput::set_active(bool active) noexcept {
  set_calls_.fetch_add(1);
  const int fail = fail_errno_.load();
  if (fail != 0) {
    last_errno_.store(fail);
    return false;
  }
  const bool before = active_.exchange(active);
  if (active && !before) {
    activations_.fetch_add(1);
  } else if (!active && before) {
    deactivations_.fetch_add(1);
  }
  return true;
}

SimFaultInput::SimFaultInput() : event_fd_(::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC)) {
  if (event_fd_ < 0) {
    throw HalError(errno, "cannot create the simulated fault input's event descriptor: " + errno_text(errno));
  }
}

SimFaultInput::~SimFaultInput() { ::close(event_fd_); }

void SimFaultInput::set_fault(bool fault) noexcept {
  if (fault_.exchange(fault) != fault) {
    const std::uint64_t one = 1;
    (void)!::write(event_fd_, &one, sizeof one);
  }
}

void SimFaultInput::fail_with(int error_number) noexcept {
  fail_errno_.store(error_number);
  const std::uint64_t one = 1;
  (void)!::write(event_fd_, &one, sizeof one);  // the next read fails: wake the watcher
}

std::optional<bool> SimFaultInput::fault_active() noexcept {
  reads_.fetch_add(1);
  std::uint64_t events = 0;
  (void)!::read(event_fd_, &events, sizeof events);  // consume the edges (non-blocking)
  const int fail = fail_errno_.load();
  if (fail != 0) {
    last_errno_.store(fail);
    return std::nullopt;
  }
  return fault_.load();
}

std::unique_ptr<GateEnableOutput> make_gate_enable_output(const GpioLineConfig& config) {
  if (config.chip.empty()) {
    return std::make_unique<NullGateEnableOutput>();
  }
  return open_gpiod_gate_enable(config);
}

std::unique_ptr<FaultInput> make_fault_input(const GpioLineConfig& config) {
  if (config.chip.empty()) {
    return std::make_unique<NullFaultInput>();
  }
  return open_gpiod_fault_input(config);
}

}  // namespace pmsm::hal
