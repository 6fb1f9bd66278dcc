// The drive node: one sensor sample (or "no sample this period") plus the operator's latest
// validated commands in, one inverter command plus the period's publications out. It owns
// the sensor front end, the drive controller and the supervisor, and it is the only
// per-sample path: pmsm-thermald's RT thread, `pmsm-thermal simulate` and the tests all run
// it, so that what the simulator measures is what the daemon does.
//
//   sample k --> front end --> supervisor (plausibility, state, faults)
//                          --> controller (current loop, injection, estimator)
//            --> inverter command for period k+1, publications (protocol messages) due now,
//                and the calibration to store when one has just completed
//
// The per-sample call allocates nothing, logs nothing, reads no clock (time is counted in
// periods) and throws nothing; what happened is in the returned record, for a non-RT side
// to publish, log and store.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>

#include "controller_config.hpp"
#include "pmsm/core/drive_controller.hpp"
#include "pmsm/core/supervisor.hpp"
#include "pmsm/hal/messages.hpp"
#include "pmsm/hal/protocol.hpp"
#include "sensor_frontend.hpp"

namespace pmsm::app {

// How often each user-facing frame is due, in seconds of drive time (0: never). Frames
// that report an event (an injection pair, a new resistance estimate, a fault changing)
// are sent when the event happens as well.
struct PublishRates {
  double thermal_estimate_s = 0.1;
  double resistance_estimate_s = 1.0;
  double drive_status_s = 0.1;
  double heartbeat_s = 1.0;
  double fault_repeat_s = 1.0;      // latched faults are repeated this often
  double stale_after_s = 60.0;      // THERMAL_ESTIMATE says stale without an accepted estimate for this long
};

// The operator's side for one period, already validated (E2E, ranges) by whoever received it.
struct NodeInputs {
  core::DriveMode mode = core::DriveMode::kDisabled;
  double speed_ref_rad_s = 0.0;      // mechanical
  double torque_ref_Nm = 0.0;
  double command_age_s = 0.0;        // since the last valid, fresh drive command
  double ambient_C = 25.0;           // ambient / coolant temperature where SENSOR_SAMPLE carries none
  bool request_injection = false;
  // One-shot requests (act on the period they are given in).
  bool start_calibration = false;
  std::optional<double> calibration_known_C;  // the winding's temperature; empty: the ambient sensor
  bool abort_calibration = false;
  bool clear_faults = false;
  std::uint32_t deadline_misses = 0; // the caller's count, for HEARTBEAT
  // How many control periods this step stands for, so that the drive's time and the
  // publication rates stay right: without a sample, the wait's (a daemon waits longer than one
  // period before it calls a sample missing); with one, 1, or the periods since the last sample
  // when the ones between were lost on the bus (the power stage's sequence numbers say so).
  std::uint32_t periods = 1;
};

// The frames due this period. A fixed-size record: it goes through the SPSC ring as is.
struct NodePublications {
  std::optional<hal::protocol::ThermalEstimate> thermal;
  std::optional<hal::protocol::ResistanceEstimate> resistance;
  std::optional<hal::protocol::InjectionReport> injection;
  std::optional<hal::protocol::DriveStatus> status;
  std::optional<hal::protocol::Heartbeat> heartbeat;
  std::array<hal::protocol::FaultReport, core::kFaultCodeCount> faults{};  // the first fault_count
  std::size_t fault_count = 0;
  // Events among the above (the rest repeats what the next period's publications say again):
  // a fault latched or cleared this period (not only the repeats of latched ones), and the
  // THERMAL_ESTIMATE sent at once for a calibration's start or end (its Calibrating bit's edge).
  bool fault_changed = false;
  bool calibrating_changed = false;

  // Nothing due. Not `= {}`: zeroing the fault reports past fault_count, which nobody reads,
  // cost a twentieth of the node's step. A field added above is reset here.
  void clear() noexcept {
    thermal.reset();
    resistance.reset();
    injection.reset();
    status.reset();
    heartbeat.reset();
    fault_count = 0;
    fault_changed = false;
    calibrating_changed = false;
  }
};

struct NodeStep {
  // The command for the period after the sample; empty when there was no sample (nothing to
  // answer: the power stage's own command timeout takes it to the safe state).
  std::optional<hal::InverterCommand> command;
  NodePublications publications;
  std::optional<core::Calibration> calibration_to_store;  // a calibration just completed
  // The calibration in use just took its Ke0 from turning events (it had none: it ran at rest),
  // to be stored as it now stands (DriveController::magnet_reference_completed).
  std::optional<core::Calibration> magnet_reference_to_store;
  bool calibration_failed = false;                        // a calibration just failed (timed out or refused)
};

// The protocol's method code for a pair's method and separation (INJECTION_REPORT Method).
[[nodiscard]] hal::protocol::InjectionMethod protocol_method(core::InjectionMethod method, core::Separation separation) noexcept;
// Its inverse: the controller's method and separation for the protocol's (INJECTION_COMMAND,
// INJECTION_REPORT); kOff is core::InjectionMethod::kNone.
struct CoreInjectionMethod {
  core::InjectionMethod method = core::InjectionMethod::kNone;
  core::Separation separation = core::Separation::kBipolar;
};
[[nodiscard]] CoreInjectionMethod core_injection_method(hal::protocol::InjectionMethod method) noexcept;

class DriveNode {
 public:
  DriveNode(const ControllerConfig& config, const core::SupervisorConfig& supervisor, const PublishRates& rates);

  // One period. `sample` null: no sample arrived this period.
  const NodeStep& step(const hal::SensorSample* sample, const NodeInputs& in) noexcept;

  // The operator's injection settings (see DriveController::configure_injection).
  void configure_injection(core::InjectionMethod method, core::Separation separation, double f_A, double interval_s) noexcept {
    static_cast<void>(controller_.configure_injection(method, separation, f_A, interval_s));
  }

  // A condition the caller watches (interface down, GPIO fault input, deadline overruns).
  void report(core::FaultCode code, bool present) noexcept { supervisor_.report(code, present); }

  [[nodiscard]] const core::DriveController& controller() const noexcept { return controller_; }
  [[nodiscard]] core::DriveController& controller() noexcept { return controller_; }
  // The ambient / coolant temperature the drive used last (the sample's sensor, or the input).
  [[nodiscard]] double ambient_C() const noexcept { return ambient_used_C_; }
  // The sensor reported and then stopped (AmbientValid cleared): ambient_C() holds its last
  // reading rather than falling back to the input (25 C by default). Cleared when it reports again.
  [[nodiscard]] bool ambient_held() const noexcept { return ambient_held_; }
  // How many times a reporting ambient sensor stopped (each a start of ambient_held()): a
  // dropout shorter than the publications' interval is counted too.
  [[nodiscard]] std::uint32_t ambient_dropouts() const noexcept { return ambient_dropouts_; }
  // A reading of the sample's sensor is in use (held or fresh), not the input.
  [[nodiscard]] bool ambient_sensed() const noexcept { return sensed_ambient_C_.has_value(); }
  // How far a restored thermal state's winding moved because the ambient at the first sample
  // was not the stored one (DriveController::refer_restored_state_to_ambient); 0 if it was.
  [[nodiscard]] double restore_ambient_shift_C() const noexcept { return restore_ambient_shift_C_; }
  [[nodiscard]] const core::Supervisor& supervisor() const noexcept { return supervisor_; }
  [[nodiscard]] const SensorFrontend& frontend() const noexcept { return frontend_; }
  [[nodiscard]] std::uint64_t periods() const noexcept { return period_; }
  [[nodiscard]] double uptime_s() const noexcept { return static_cast<double>(period_) * period_s_; }

 private:
  void publish(const NodeInputs& in) noexcept;
  void publish_fault_changes(bool repeat_due) noexcept;
  // Whether a multiple of `every` periods falls in [period_, period_ + advance_).
  [[nodiscard]] bool due(std::uint64_t every) const noexcept {
    return every != 0U && (period_ == 0U || (period_ - 1U) / every != (period_ + advance_ - 1U) / every);
  }
  [[nodiscard]] std::uint64_t every(double seconds) const noexcept;

  core::DriveController controller_;
  core::Supervisor supervisor_;
  SensorFrontend frontend_;
  bool noise_known_ = false;  // the sensors' noise handed to the controller
  std::uint16_t reported_period_code_ = 0;  // the power stage's last reported PWM period (its code)
  // The sequence of the last sample the controller used (DriveInput::continuous).
  std::optional<std::uint32_t> last_used_sequence_;
  double period_s_;
  PublishRates rates_;
  std::uint64_t thermal_every_;
  std::uint64_t resistance_every_;
  std::uint64_t status_every_;
  std::uint64_t heartbeat_every_;
  std::uint64_t fault_every_;
  std::uint64_t period_ = 0;
  std::uint64_t advance_ = 1;  // periods this step stands for
  // The end of the last step whose speed and torque were the tracker's present reading
  // (DriveController::motion_known), 0 before any: DRIVE_STATUS's MotionValid.
  std::uint64_t motion_known_until_ = 0;
  // DRIVE_STATUS's torque over its interval: the sums of iq and id iq of the periods the tracker
  // followed the shaft, and their count.
  double torque_iq_sum_A_ = 0.0;
  double torque_idiq_sum_A2_ = 0.0;
  std::uint32_t torque_samples_ = 0;
  NodeStep out_{};
  std::uint32_t published_latched_ = 0;   // the latched mask as last published
  std::array<double, core::kFaultCodeCount> fault_changed_s_{};
  // A calibration at real thermal time (ControllerConfig::calibration_real_time): the
  // thermal time scale to return to, and whether a calibration runs at 1 now.
  double thermal_time_scale_;
  bool calibration_real_time_;
  bool real_time_calibration_ = false;
  bool calibrating_published_ = false;  // THERMAL_ESTIMATE's Calibrating bit as last published
  std::optional<double> sensed_ambient_C_;  // the sample's ambient sensor, last plausible reading
  bool ambient_held_ = false;
  std::uint32_t ambient_dropouts_ = 0;
  bool restore_referred_ = false;  // the first plausible sample's ambient went to a restored state
  double restore_ambient_shift_C_ = 0.0;
  double ambient_used_C_ = 25.0;
  std::uint8_t heartbeat_counter_ = 0;
  std::uint8_t injection_count_ = 0;
  std::uint16_t estimate_count_ = 0;
  std::optional<double> last_estimate_s_;  // last accepted (fused) resistance estimate
  std::optional<core::ResistanceEstimate> last_estimate_;
};

// The supervisor's limits for the configured drive, relative to it: the DC-bus window
// around the nominal bus, the over-current trip below the current ADC's full scale, the
// encoder speed limit from the rated speed, the trip temperature above the derating limit.
[[nodiscard]] core::SupervisorConfig default_supervisor_config(const ControllerConfig& config);


}  // namespace pmsm::app
