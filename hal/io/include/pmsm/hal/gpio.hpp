// GPIO as the daemon needs it: the power stage's gate-enable output and its fault input.
//
// Backends:
//   null  - no chip configured: the enable does nothing, the fault input never reports a
//           fault; backend_name() says "null" so the daemon can log that once.
//   sim   - for tests: counts calls, holds the level, fault and failures settable.
//   gpiod - libgpiod 1.6 (the only file that includes gpiod.h is hal/io/src/gpio_gpiod.cpp,
//           because libgpiod 2.x has a different API).
// The enable line is requested as an output that is INACTIVE at request time, so that
// opening it never switches the gates on; assert it only after start-up checks. When the
// process dies the kernel releases the line and it may float: the board needs a pull-down
// (pull-up if active-low) on the gate-enable signal, see docs/hal.md.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <variant>

#include "pmsm/hal/status.hpp"

namespace pmsm::hal {

inline constexpr std::string_view kGpioConsumer = "pmsm-thermald";

class GateEnableOutput {
 public:
  GateEnableOutput() = default;
  virtual ~GateEnableOutput() = default;
  GateEnableOutput(const GateEnableOutput&) = delete;
  GateEnableOutput& operator=(const GateEnableOutput&) = delete;

  // Drives the line active (gates may switch) or inactive (safe). False if the kernel
  // refused; last_error_number() tells why. Never throws, never allocates.
  [[nodiscard]] virtual bool set_active(bool active) noexcept = 0;
  // The level last set successfully (false until set_active(true) succeeded).
  [[nodiscard]] virtual bool active() const noexcept = 0;
  [[nodiscard]] virtual int last_error_number() const noexcept = 0;
  [[nodiscard]] virtual std::string_view backend_name() const noexcept = 0;
  // "gpiochip0 line 17 ('GATE_EN')", or the backend name: for log lines.
  [[nodiscard]] virtual std::string describe() const = 0;
};

class FaultInput {
 public:
  FaultInput() = default;
  virtual ~FaultInput() = default;
  FaultInput(const FaultInput&) = delete;
  FaultInput& operator=(const FaultInput&) = delete;

  // True if the power stage reports a fault (its level, or an edge since the last read: a pulse
  // that has ended), false if not, nothing if the read failed
  // (a failed read is not "no fault": the caller decides, typically the safe state).
  // Consumes the edge events that made event_fd() readable.
  [[nodiscard]] virtual std::optional<bool> fault_active() noexcept = 0;
  // A descriptor that becomes readable when the line changes (the kernel's edge events), or
  // -1 when the backend has none and must be polled.
  [[nodiscard]] virtual int event_fd() const noexcept { return -1; }
  [[nodiscard]] virtual int last_error_number() const noexcept = 0;
  [[nodiscard]] virtual std::string_view backend_name() const noexcept = 0;
  [[nodiscard]] virtual std::string describe() const = 0;
};

// Where a line is: chip by name ("gpiochip0"), path ("/dev/gpiochip0"), label or number
// (as gpiod_chip_open_lookup() accepts); line by offset or by name.
struct GpioLineConfig {
  std::string chip;  // empty: no chip configured -> null backend
  std::variant<unsigned int, std::string> line = 0U;
  bool active_low = false;  // the physical level is inverted: "active" drives it low
};

// Null backends.
class NullGateEnableOutput final : public GateEnableOutput {
 public:
  [[nodiscard]] bool set_active(bool active) noexcept override;
  [[nodiscard]] bool active() const noexcept override { return active_; }
  [[nodiscard]] int last_error_number() const noexcept override { return 0; }
  [[nodiscard]] std::string_view backend_name() const noexcept override { return "null"; }
  [[nodiscard]] std::string describe() const override { return "null"; }

 private:
  bool active_ = false;
};

class NullFaultInput final : public FaultInput {
 public:
  [[nodiscard]] std::optional<bool> fault_active() noexcept override { return false; }
  [[nodiscard]] int last_error_number() const noexcept override { return 0; }
  [[nodiscard]] std::string_view backend_name() const noexcept override { return "null"; }
  [[nodiscard]] std::string describe() const override { return "null"; }
};

// Sim backends: thread-safe (a test thread may set a fault while the RT thread reads).
class SimGateEnableOutput final : public GateEnableOutput {
 public:
  [[nodiscard]] bool set_active(bool active) noexcept override;
  [[nodiscard]] bool active() const noexcept override { return active_.load(); }
  [[nodiscard]] int last_error_number() const noexcept override { return last_errno_.load(); }
  [[nodiscard]] std::string_view backend_name() const noexcept override { return "sim"; }
  [[nodiscard]] std::string describe() const override { return "sim"; }

  // Every call to set_active, and the calls that changed the level.
  [[nodiscard]] std::uint64_t set_calls() const noexcept { return set_calls_.load(); }
  [[nodiscard]] std::uint64_t activations() const noexcept { return activations_.load(); }
  [[nodiscard]] std::uint64_t deactivations() const noexcept { return deactivations_.load(); }
  // Makes the following set_active calls fail with `error_number` (0: succeed again).
  void fail_with(int error_number) noexcept { fail_errno_.store(error_number); }

 private:
  std::atomic<bool> active_{false};
  std::atomic<int> last_errno_{0};
  std::atomic<int> fail_errno_{0};
  std::atomic<std::uint64_t> set_calls_{0};
  std::atomic<std::uint64_t> activations_{0};
  std::atomic<std::uint64_t> deactivations_{0};
};

// Signals each change on an eventfd, as the kernel signals an edge.
class SimFaultInput final : public FaultInput {
 public:
  SimFaultInput();
  ~SimFaultInput() override;
  SimFaultInput(const SimFaultInput&) = delete;
  SimFaultInput& operator=(const SimFaultInput&) = delete;
  [[nodiscard]] std::optional<bool> fault_active() noexcept override;
  [[nodiscard]] int event_fd() const noexcept override { return event_fd_; }
  [[nodiscard]] int last_error_number() const noexcept override { return last_errno_.load(); }
  [[nodiscard]] std::string_view backend_name() const noexcept override { return "sim"; }
  [[nodiscard]] std::string describe() const override { return "sim"; }

  void set_fault(bool fault) noexcept;  // an edge when the level changes
  void fail_with(int error_number) noexcept;
  [[nodiscard]] std::uint64_t reads() const noexcept { return reads_.load(); }

 private:
  std::atomic<bool> fault_{false};
  std::atomic<int> last_errno_{0};
  std::atomic<int> fail_errno_{0};
  std::atomic<std::uint64_t> reads_{0};
  int event_fd_ = -1;
};

// libgpiod 1.6 backends. The constructors throw HalError naming chip and line, e.g.
//   "GPIO chip 'gpiochip0' for the gate enable not found: No such file or directory"
//   "GPIO chip 'gpiochip0' (gpiochip0, pinctrl-bcm2711, 58 lines) has no line 'GATE_EN'
//    for the gate enable: No such file or directory"
//   "GPIO gpiochip0 line 17 ('GATE_EN') for the gate enable is busy (used by 'other')"
// The enable line is requested as an output, inactive, with consumer "pmsm-thermald"; the
// fault line as an input with events on both edges (event_fd() is the kernel's).
std::unique_ptr<GateEnableOutput> open_gpiod_gate_enable(const GpioLineConfig& config);
std::unique_ptr<FaultInput> open_gpiod_fault_input(const GpioLineConfig& config);

// The configured backend: null if config.chip is empty, else gpiod (which may throw).
std::unique_ptr<GateEnableOutput> make_gate_enable_output(const GpioLineConfig& config);
std::unique_ptr<FaultInput> make_fault_input(const GpioLineConfig& config);

}  // namespace pmsm::hal
