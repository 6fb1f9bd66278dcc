// The drive supervisor: the drive's state machine, input plausibility and latched faults.
//
// Pure and deterministic, like the rest of core/: the caller hands in one period's facts
// (the sample or "no sample this period", whether the operator asks for torque, the age of
// the last valid command, the thermal estimate) and gets back whether the power stage may
// switch in the next period. No clock is read; time is counted in periods.
//
// Faults are kept apart from limits, as moteus keeps `errc` faults apart from limit reasons:
//   - A fault is latched when its cause appears, puts the drive in kFault (gates off, the
//     current loop does not run) and stays until a clear-faults request finds its cause gone.
//     Each FaultCode has its own counter; a fault that is already latched is not counted
//     again while it persists.
//   - Losing the power stage is the one fault that clears itself: a sensor timeout, and an
//     interface loss the caller no longer reports, clear when samples come back (for
//     `sensor_recovery_periods` in a row); the drive then resumes what the operator commands,
//     so that a restarted plant or a reconnected bus needs no operator (docs/drive.md).
//   - Limits (derating from the thermal estimate, the voltage limit) are not faults: they
//     never latch and never switch the gates off; the controller reports them.
//
// An implausible measurement never becomes a plausible number: a sample with a non-finite
// value, a DC bus outside its window, an over-current, a phase-current sum far from zero or
// an encoder jump is refused before the controller sees it, and the refusal is a fault.
#pragma once

#include <array>
#include <cstdint>
#include <optional>

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

// The protocol's DriveState numbering (hal/protocol: a unit test checks it).
enum class DriveState : std::uint8_t {
  kInit = 0,         // starting up (ADC offset calibration), gates off
  kStandby = 1,      // ready, gates off (not enabled)
  kRunning = 2,      // gates on, torque or speed control
  kCalibrating = 3,  // gates on, Rs0 calibration in progress
  kFault = 4,        // safe state: gates off until the faults are cleared
};

// The protocol's FaultCode numbering (hal/protocol: a unit test checks it).
enum class FaultCode : std::uint8_t {
  kNone = 0,
  kSensorTimeout = 1,        // no sensor sample for sensor_timeout_periods
  kOvercurrent = 2,          // a phase current above overcurrent_A
  kOvertemperature = 3,      // winding estimate above trip_temp_C
  kBusOff = 4,               // CAN controller bus-off (reported by the caller)
  kInterfaceDown = 5,        // CAN interface down or gone (reported by the caller)
  kCommandTimeout = 6,       // no valid, fresh command while enabled
  kGpioFault = 7,            // GPIO fault input asserted (reported by the caller)
  kConfig = 8,
  kHardwareOvercurrent = 9,  // the power stage's own comparator (sensor flag)
  kDeadlineOverrun = 10,     // (reported by the caller)
  kCalibrationFailed = 11,
  kStorage = 12,
  kInternal = 13,            // the controller produced a non-finite or out-of-range output
  kDcBusUndervoltage = 14,
  kDcBusOvervoltage = 15,
  kInputNotFinite = 16,      // NaN or infinity in a measurement
  kEncoderJump = 17,         // the angle moved more in one period than the speed allows
  kCurrentSum = 18,          // |ia + ib + ic| too large: a broken phase-current sensor
  kAmbientImplausible = 19,  // the ambient / coolant sensor reads outside its plausible window
  kOverspeed = 20,           // the shaft turns faster than overspeed_rad_s (over a 1 ms window)
  kPeriodMismatch = 21,      // the power stage reports another sampling period than the drive's
  kCurrentOffset = 22,       // a current sensor read far from zero with the gates off at power-up
  kOutputFeedback = 23,      // the power stage kept its gates off while the drive enabled them, or on while it held them off
  kDuplicateNode = 24,       // another sender transmits this node's frames, published or samples (reported by the caller)
  kCount = 25,
};

[[nodiscard]] const char* to_string(DriveState state) noexcept;
[[nodiscard]] const char* to_string(FaultCode code) noexcept;

inline constexpr std::size_t kFaultCodeCount = static_cast<std::size_t>(FaultCode::kCount);

struct SupervisorConfig {
  double dc_bus_min_V = 400.0;           // below: under-voltage trip
  double dc_bus_max_V = 800.0;           // above: over-voltage trip
  double overcurrent_A = 180.0;          // any phase current above: trip (below the ADC range)
  double current_sum_max_A = 20.0;       // |ia + ib + ic| above: a phase sensor is broken
  // A phase's power-up offset (its mean reading with the gates off) further from zero than
  // this: a broken or stuck sensor, whose readings the offset would turn into plausible ones.
  double current_offset_max_A = 10.0;
  double max_speed_rad_s = 1000.0;       // mechanical; the encoder may not move faster
  // Mechanical; the encoder's speed over a window of about 1 ms above this trips the drive
  // (an overhauling load, a runaway in torque control). 0: off. Below max_speed_rad_s.
  double overspeed_rad_s = 500.0;
  int encoder_counts = 16384;            // counts per mechanical revolution
  int sensor_timeout_periods = 10;       // periods without a sample before the fault
  int sensor_recovery_periods = 10;      // periods with samples before it clears itself
  // Samples in a row reporting the gates off (SENSOR_SAMPLE's OutputEnabled) while the drive
  // has enabled them: the stage is not doing what it is told (an open enable chain, a safe
  // torque off, a stage that latched a fault of its own). 0: not judged.
  int output_feedback_periods = 100;
  double command_timeout_s = 0.0;        // enabled without a fresh command this long: trip (0: off)
  double trip_temp_C = 180.0;            // winding estimate above: over-temperature trip
  double trip_hysteresis_C = 10.0;       // may be cleared once below trip - hysteresis
  double ambient_min_C = -50.0;          // ambient / coolant sensor window: outside, the
  double ambient_max_C = 130.0;          // reading is implausible (the thermal model's input)
};

// The sample's measurements, as the sensor front end scaled them.
struct SupervisedSample {
  Abc i_A{};
  double vdc_V = 0.0;
  std::uint32_t encoder_count = 0;
  bool hardware_overcurrent = false;
  bool output_enabled = true;       // the stage's report that its gates switch (a sample without one: true)
  std::optional<double> ambient_C;  // the ambient / coolant sensor, if the sample carries it
};

struct SupervisorInput {
  std::optional<SupervisedSample> sample;  // empty: no sample this period
  // Control periods this step stands for: 1 with a sample; a step without one may stand for
  // several (the daemon's sample timeout). The encoder's checks judge the angle's step over the
  // periods that really passed.
  std::uint32_t periods = 1;
  bool frontend_ready = false;             // the ADC offset calibration is done
  Abc current_offsets_A{};                 // its offsets, once ready (judged every period)
  bool enable_requested = false;           // the operator's command asks for torque
  bool calibrating = false;                // the controller runs an Rs0 calibration
  double command_age_s = 0.0;              // since the last valid, fresh command
  std::optional<double> winding_C;         // the thermal estimate, if there is one
};

struct SupervisorStatus {
  DriveState state = DriveState::kInit;
  bool power_stage_enabled = false;        // the gates may switch in the next period
  bool sample_usable = false;              // this period's sample passed every check
  std::uint32_t latched_mask = 0;          // bit per FaultCode: latched now
  FaultCode first_fault = FaultCode::kNone; // the fault that led into kFault
  std::uint32_t missing_samples = 0;       // consecutive periods without a sample
  double reported_period_s = 0.0;          // the last period the power stage reported (0: none)
};

class Supervisor {
 public:
  Supervisor(const SupervisorConfig& config, double period_s);

  // One period. Plausibility of the sample first, then the state machine.
  const SupervisorStatus& step(const SupervisorInput& in) noexcept;

  // A condition the caller watches (interface down, GPIO fault input, bus-off, deadline
  // overruns): while present it is a cause; it latches the fault at the next step() and
  // keeps a clear request from clearing it.
  void report(FaultCode code, bool present) noexcept;

  // The power stage's PWM (sampling) period, as its samples report it, whenever that changes
  // (not per period: it is the same in every sample of one power stage). Every clock of the
  // drive (the current loop's gains, the PLL, the thermal model's time, the injection's timing)
  // assumes its own period, so another one is a cause of PERIOD_MISMATCH until a matching one
  // is reported; a match is within one step of the report's resolution (`step_s`, which the
  // drive's own period need not lie on) or 0.1 %. Not finite or not positive: the stage
  // reports none, nothing is judged, and a mismatch reported before stops being a cause.
  void set_reported_period(double period_s, double step_s) noexcept;

  // A one-off fault the caller detected (a non-finite controller output, ...): latched at
  // once, gates off from now on; its cause is gone as soon as it is reported.
  void trip(FaultCode code) noexcept;

  // The operator's clear-faults request: every latched fault whose cause is gone is
  // cleared at the next step(); the others stay (and stay counted once).
  void request_clear() noexcept { clear_requested_ = true; }

  [[nodiscard]] const SupervisorStatus& status() const noexcept { return status_; }
  [[nodiscard]] bool latched(FaultCode code) const noexcept {
    return (status_.latched_mask & bit(code)) != 0U;
  }
  [[nodiscard]] bool cause_present(FaultCode code) const noexcept {
    return (cause_mask_ & bit(code)) != 0U;
  }
  // The last step had a sample whose readings are plausible as a frame: none a sensor cannot give
  // (a reading not a number, an encoder count or an angle step the encoder cannot make, phase
  // currents that do not sum to zero, an ambient out of range). A real condition it reports (a
  // bus switched off, an overcurrent) leaves its other readings good.
  [[nodiscard]] bool sample_plausible() const noexcept { return sample_plausible_; }
  // Times each fault was latched (indexed by FaultCode).
  [[nodiscard]] const std::array<std::uint32_t, kFaultCodeCount>& counts() const noexcept { return counts_; }
  // What each fault's cause measured when it last latched (indexed by FaultCode), for the log:
  // the DC bus (V) for its two faults, the largest phase current (A), |ia + ib + ic| (A), the
  // ambient sensor (C), the angle's step (encoder counts), the winding estimate (C), the
  // shaft's speed (rad/s), the periods without a sample, the command's age (s); 0 for the
  // faults the caller reports.
  [[nodiscard]] const std::array<double, kFaultCodeCount>& latched_values() const noexcept { return latched_value_; }
  [[nodiscard]] const SupervisorConfig& config() const noexcept { return config_; }

  [[nodiscard]] static constexpr std::uint32_t bit(FaultCode code) noexcept {
    return std::uint32_t{1} << static_cast<unsigned>(code);
  }

 private:
  void latch(FaultCode code) noexcept;
  // A cause present this period, with what it measured.
  void cause(FaultCode code, double value) noexcept;
  // Sets cause_mask_ bits for this sample's implausible measurements.
  void check_sample(const SupervisedSample& s) noexcept;

  SupervisorConfig config_;
  double period_s_;
  double max_step_counts_;
  SupervisorStatus status_{};
  std::array<std::uint32_t, kFaultCodeCount> counts_{};
  std::array<double, kFaultCodeCount> cause_value_{};    // what each cause measured when last seen
  std::array<double, kFaultCodeCount> latched_value_{};  // ... when its fault last latched
  std::uint32_t cause_mask_ = 0;   // causes present this period
  bool sample_plausible_ = false;  // sample_plausible()
  std::uint32_t external_mask_ = 0;  // caller-reported causes (cleared by request_clear when gone)
  bool clear_requested_ = false;
  bool have_encoder_ = false;
  std::uint32_t last_encoder_ = 0;
  std::uint32_t present_samples_ = 0;
  bool overtemp_cause_ = false;
  // The overspeed check: encoder counts moved and periods elapsed in the current window.
  int overspeed_window_periods_ = 10;
  std::int64_t window_counts_ = 0;
  std::uint32_t window_periods_ = 0;
  std::uint32_t periods_without_sample_ = 0;  // since the last sample, as the steps said
  std::uint32_t output_off_samples_ = 0;      // in a row reporting the gates off while enabled
  std::uint32_t output_on_samples_ = 0;       // in a row reporting the gates on while held off
  bool overspeed_cause_ = false;
};

}  // namespace pmsm::core
