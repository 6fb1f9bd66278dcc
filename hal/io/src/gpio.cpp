// Null and simulated GPIO backends, and the choice between null and libgpiod.
#include "pmsm/hal/gpio.hpp"

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

std::optional<bool> SimFaultInput::fault_active() noexcept {
  reads_.fetch_add(1);
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
