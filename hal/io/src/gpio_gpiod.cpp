// libgpiod 1.6 backends. The whole libgpiod dependency lives in this file: libgpiod 2.x
// replaced the line/request API (gpiod_line_request_output and friends no longer exist),
// so moving to it means rewriting this file only.
#include <gpiod.h>

#include <array>
#include <cerrno>
#include <ctime>
#include <string>

#include "pmsm/hal/gpio.hpp"

namespace pmsm::hal {

namespace {

const std::string kConsumer{kGpioConsumer};

struct ChipCloser {
  void operator()(gpiod_chip* chip) const noexcept { gpiod_chip_close(chip); }
};
using ChipPtr = std::unique_ptr<gpiod_chip, ChipCloser>;

std::string line_text(const GpioLineConfig& config) {
  if (const auto* offset = std::get_if<unsigned int>(&config.line)) {
    return "line " + std::to_string(*offset);
  }
  return "line '" + std::get<std::string>(config.line) + "'";
}

// An open chip and one line of it, requested by the caller.
struct OpenLine {
  ChipPtr chip;
  gpiod_line* line = nullptr;  // owned by the chip
  std::string description;     // "gpiochip0 line 17 ('GATE_EN')"
};

OpenLine find_line(const GpioLineConfig& config, const char* role) {
  errno = 0;
  ChipPtr chip{gpiod_chip_open_lookup(config.chip.c_str())};
  if (!chip) {
    const int e = errno != 0 ? errno : ENOENT;
    throw HalError(e, "GPIO chip '" + config.chip + "' for the " + role + " not found: " + errno_text(e));
  }
  const std::string chip_name = gpiod_chip_name(chip.get());
  const std::string chip_text = "GPIO chip '" + config.chip + "' (" + chip_name + ", " +
                                gpiod_chip_label(chip.get()) + ", " +
                                std::to_string(gpiod_chip_num_lines(chip.get())) + " lines)";
  gpiod_line* line = nullptr;
  if (const auto* offset = std::get_if<unsigned int>(&config.line)) {
    if (*offset >= gpiod_chip_num_lines(chip.get())) {
      throw HalError(EINVAL, chip_text + " has no line " + std::to_string(*offset) + " for the " + role);
    }
    line = gpiod_chip_get_line(chip.get(), *offset);
  } else {
    line = gpiod_chip_find_line(chip.get(), std::get<std::string>(config.line).c_str());
  }
  if (line == nullptr) {
    const int e = errno != 0 ? errno : ENOENT;
    throw HalError(e, chip_text + " has no " + line_text(config) + " for the " + role + ": " + errno_text(e));
  }
  OpenLine result;
  result.description = chip_name + " line " + std::to_string(gpiod_line_offset(line));
  if (const char* name = gpiod_line_name(line); name != nullptr) {
    result.description += std::string{" ('"} + name + "')";
  }
  if (gpiod_line_is_used(line)) {
    const char* consumer = gpiod_line_consumer(line);
    throw HalError(EBUSY, "GPIO " + result.description + " for the " + role + " is busy (used by '" +
                              (consumer != nullptr ? consumer : "the kernel") + "')");
  }
  result.chip = std::move(chip);
  result.line = line;
  return result;
}

[[noreturn]] void throw_request_failed(const OpenLine& l, const char* role, const char* as) {
  const int e = errno;
  throw HalError(e, "cannot request GPIO " + l.description + " for the " + role + " as " + as + ": " +
                        errno_text(e));
}

class GpiodGateEnableOutput final : public GateEnableOutput {
 public:
  explicit GpiodGateEnableOutput(const GpioLineConfig& config) : line_(find_line(config, "gate enable")) {
    const int flags = config.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
    // Requested INACTIVE: opening the line must never switch the gates on.
    if (gpiod_line_request_output_flags(line_.line, kConsumer.c_str(), flags, 0) != 0) {
      throw_request_failed(line_, "gate enable", "an output");
    }
  }
  ~GpiodGateEnableOutput() override {
    // Leave the gates off before giving the line back (then the board's pull resistor holds it).
    (void)gpiod_line_set_value(line_.line, 0);
    gpiod_line_release(line_.line);
  }
  GpiodGateEnableOutput(const GpiodGateEnableOutput&) = delete;
  GpiodGateEnableOutput& operator=(const GpiodGateEnableOutput&) = delete;

  [[nodiscard]] bool set_active(bool active) noexcept override {
    if (gpiod_line_set_value(line_.line, active ? 1 : 0) != 0) {
      last_errno_ = errno;
      return false;
    }
    active_ = active;
    return true;
  }
  [[nodiscard]] bool active() const noexcept override { return active_; }
  [[nodiscard]] int last_error_number() const noexcept override { return last_errno_; }
  [[nodiscard]] std::string_view backend_name() const noexcept override { return "gpiod"; }
  [[nodiscard]] std::string describe() const override { return "gpiod " + line_.description; }

 private:
  OpenLine line_;
  bool active_ = false;
  int last_errno_ = 0;
};

class GpiodFaultInput final : public FaultInput {
 public:
  explicit GpiodFaultInput(const GpioLineConfig& config) : line_(find_line(config, "fault input")) {
    const int flags = config.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
    // Edge events on both edges: the daemon wakes on the kernel's interrupt, not a poll.
    if (gpiod_line_request_both_edges_events_flags(line_.line, kConsumer.c_str(), flags) != 0) {
      throw_request_failed(line_, "fault input", "an input with edge events");
    }
    event_fd_ = gpiod_line_event_get_fd(line_.line);
  }
  ~GpiodFaultInput() override { gpiod_line_release(line_.line); }
  GpiodFaultInput(const GpiodFaultInput&) = delete;
  GpiodFaultInput& operator=(const GpiodFaultInput&) = delete;

  [[nodiscard]] int event_fd() const noexcept override { return event_fd_; }

  [[nodiscard]] std::optional<bool> fault_active() noexcept override {
    // Consume the pending edges. Any edge is a fault: a pulse shorter than this thread's wake
    // (a desaturation comparator, a gate driver's self-resetting FAULT) has ended by the time
    // the level below is read, and the edges are all that is left of it. (A quiet fault line
    // has no edges; the level then decides.) Bounded: a line chattering faster than this reads
    // must not keep the level unread.
    const timespec none{0, 0};
    bool edges = false;
    for (int batch = 0; event_fd_ >= 0 && batch < 4; ++batch) {
      const int pending = gpiod_line_event_wait(line_.line, &none);
      if (pending < 0) {
        last_errno_ = errno;
        return std::nullopt;
      }
      if (pending == 0) {
        break;
      }
      std::array<gpiod_line_event, 16> events{};
      const int read = gpiod_line_event_read_multiple(line_.line, events.data(), static_cast<unsigned>(events.size()));
      if (read < 0) {
        last_errno_ = errno;
        return std::nullopt;
      }
      edges = edges || read > 0;
    }
    const int value = gpiod_line_get_value(line_.line);
    if (value < 0) {
      last_errno_ = errno;
      return std::nullopt;
    }
    return edges || value != 0;
  }
  [[nodiscard]] int last_error_number() const noexcept override { return last_errno_; }
  [[nodiscard]] std::string_view backend_name() const noexcept override { return "gpiod"; }
  [[nodiscard]] std::string describe() const override { return "gpiod " + line_.description; }

 private:
  OpenLine line_;
  int last_errno_ = 0;
  int event_fd_ = -1;
};

}  // namespace

std::unique_ptr<GateEnableOutput> open_gpiod_gate_enable(const GpioLineConfig& config) {
  return std::make_unique<GpiodGateEnableOutput>(config);
}

std::unique_ptr<FaultInput> open_gpiod_fault_input(const GpioLineConfig& config) {
  return std::make_unique<GpiodFaultInput>(config);
}

}  // namespace pmsm::hal
