// The frame codec: typed messages <-> CAN frames, driven by the signal tables of
// protocol.hpp (every start bit, length, factor and range comes from there).
#include "pmsm/hal/codec.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <type_traits>
#include <utility>
#include <variant>

#include "bits.hpp"
#include "pmsm/hal/crc8.hpp"

namespace pmsm::hal::protocol {
namespace {

using detail::get_bits_le;
using detail::put_bits_le;
using detail::sign_extend;

// ---------------------------------------------------------------------------------------
// Writing signals
// ---------------------------------------------------------------------------------------

class Writer {
 public:
  explicit Writer(CanFrame& frame) noexcept : frame_(frame) {}

  void raw(const SignalDef& s, std::int64_t raw) noexcept {
    put_bits_le(frame_.data.data(), s.start_bit, s.length, static_cast<std::uint64_t>(raw));
  }

  void boolean(const SignalDef& s, bool value) noexcept { raw(s, value ? 1 : 0); }

  // A physical value, rounded to the raw grid and clamped to [minimum, maximum].
  void physical(const SignalDef& s, double value) noexcept {
    if (!std::isfinite(value)) {
      raw(s, std::clamp<std::int64_t>(0, s.raw_min(), s.raw_max()));
      worsen(EncodeStatus::kInvalidValue);
      return;
    }
    const double scaled = std::round((value - s.offset) / s.factor);
    const auto lo = static_cast<double>(s.raw_min());
    const auto hi = static_cast<double>(s.raw_max());
    if (scaled < lo) {
      raw(s, s.raw_min());
      worsen(EncodeStatus::kSaturated);
    } else if (scaled > hi) {
      raw(s, s.raw_max());
      worsen(EncodeStatus::kSaturated);
    } else {
      raw(s, static_cast<std::int64_t>(scaled));
    }
  }

  // A physical value guarded by a validity bit: 0 on the wire when not valid.
  void guarded(const SignalDef& s, bool valid, double value) noexcept {
    if (valid) {
      physical(s, value);
    } else {
      raw(s, 0);
    }
  }

  // A value-table signal; an enumerator outside the table is an invalid value.
  template <class Enum>
  void enumeration(const SignalDef& s, Enum value) noexcept {
    const auto v = static_cast<std::int64_t>(static_cast<std::underlying_type_t<Enum>>(value));
    if (v < s.raw_min() || v > s.raw_max()) {
      raw(s, 0);
      worsen(EncodeStatus::kInvalidValue);
      return;
    }
    raw(s, v);
  }

  // A count that saturates at the signal's maximum.
  void saturating(const SignalDef& s, std::uint64_t value) noexcept {
    const auto hi = static_cast<std::uint64_t>(s.raw_max());
    if (value > hi) {
      raw(s, s.raw_max());
      worsen(EncodeStatus::kSaturated);
    } else {
      raw(s, static_cast<std::int64_t>(value));
    }
  }

  // A code whose 0 means "not reported": one the signal cannot hold goes out as 0 (not wrapped)
  // and is an invalid value.
  void code_or_none(const SignalDef& s, std::uint64_t value) noexcept {
    if (value > static_cast<std::uint64_t>(s.raw_max())) {
      raw(s, 0);
      worsen(EncodeStatus::kInvalidValue);
    } else {
      raw(s, static_cast<std::int64_t>(value));
    }
  }

  // A counter that wraps modulo 2^length.
  void wrapping(const SignalDef& s, std::uint64_t value) noexcept {
    put_bits_le(frame_.data.data(), s.start_bit, s.length, value);
  }

  [[nodiscard]] EncodeStatus status() const noexcept { return status_; }

 private:
  void worsen(EncodeStatus status) noexcept { status_ = std::max(status_, status); }

  CanFrame& frame_;
  EncodeStatus status_ = EncodeStatus::kOk;
};

// ---------------------------------------------------------------------------------------
// Reading signals
// ---------------------------------------------------------------------------------------

class Reader {
 public:
  explicit Reader(const CanFrame& frame) noexcept : frame_(frame) {}

  [[nodiscard]] std::int64_t raw(const SignalDef& s) const noexcept {
    const std::uint64_t bits = get_bits_le(frame_.data.data(), s.start_bit, s.length);
    return s.is_signed ? sign_extend(bits, s.length) : static_cast<std::int64_t>(bits);
  }
  [[nodiscard]] bool boolean(const SignalDef& s) const noexcept { return raw(s) != 0; }
  [[nodiscard]] double physical(const SignalDef& s) const noexcept { return s.raw_to_physical(raw(s)); }
  [[nodiscard]] double guarded(const SignalDef& s, bool valid) const noexcept {
    return valid ? physical(s) : std::numeric_limits<double>::quiet_NaN();
  }
  template <class Enum>
  [[nodiscard]] Enum enumeration(const SignalDef& s) const noexcept {
    return static_cast<Enum>(static_cast<std::underlying_type_t<Enum>>(raw(s)));
  }
  template <class Int>
  [[nodiscard]] Int integer(const SignalDef& s) const noexcept {
    return static_cast<Int>(raw(s));
  }

 private:
  const CanFrame& frame_;
};

// ---------------------------------------------------------------------------------------
// Message bodies: one write_body / read_body pair per message
// ---------------------------------------------------------------------------------------

// Type -> MessageType, one overload per message.
constexpr MessageType type_of(std::type_identity<InverterCommand> /*unused*/) { return MessageType::kInverterCommand; }
constexpr MessageType type_of(std::type_identity<SensorSample> /*unused*/) { return MessageType::kSensorSample; }
constexpr MessageType type_of(std::type_identity<DriveCommand> /*unused*/) { return MessageType::kDriveCommand; }
constexpr MessageType type_of(std::type_identity<InjectionCommand> /*unused*/) { return MessageType::kInjectionCommand; }
constexpr MessageType type_of(std::type_identity<CalibrationCommand> /*unused*/) { return MessageType::kCalibrationCommand; }
constexpr MessageType type_of(std::type_identity<FaultReport> /*unused*/) { return MessageType::kFault; }
constexpr MessageType type_of(std::type_identity<DriveStatus> /*unused*/) { return MessageType::kDriveStatus; }
constexpr MessageType type_of(std::type_identity<ThermalEstimate> /*unused*/) { return MessageType::kThermalEstimate; }
constexpr MessageType type_of(std::type_identity<ResistanceEstimate> /*unused*/) { return MessageType::kResistanceEstimate; }
constexpr MessageType type_of(std::type_identity<InjectionReport> /*unused*/) { return MessageType::kInjectionReport; }
constexpr MessageType type_of(std::type_identity<Heartbeat> /*unused*/) { return MessageType::kHeartbeat; }
constexpr MessageType type_of(std::type_identity<ReceiveStatus> /*unused*/) { return MessageType::kReceiveStatus; }
constexpr MessageType type_of(std::type_identity<LoopTiming> /*unused*/) { return MessageType::kLoopTiming; }
constexpr MessageType type_of(std::type_identity<TruthThermal> /*unused*/) { return MessageType::kTruthThermal; }
constexpr MessageType type_of(std::type_identity<TruthElectrical> /*unused*/) { return MessageType::kTruthElectrical; }
constexpr MessageType type_of(std::type_identity<PlantStatus> /*unused*/) { return MessageType::kPlantStatus; }

template <class T>
inline constexpr MessageType kTypeOf = type_of(std::type_identity<T>{});

template <class T>
constexpr const MessageDef& def_of() noexcept {
  return message_def(kTypeOf<T>);
}

void write_body(Writer& w, const InverterCommand& m) noexcept {
  using namespace inverter_command;
  w.raw(kSequence, m.sequence);
  w.raw(kDutyA, m.duty[0]);
  w.raw(kDutyB, m.duty[1]);
  w.raw(kDutyC, m.duty[2]);
  w.boolean(kEnable, m.enable);
}
void read_body(const Reader& r, InverterCommand& m) noexcept {
  using namespace inverter_command;
  m.sequence = r.integer<std::uint32_t>(kSequence);
  m.duty[0] = r.integer<std::uint16_t>(kDutyA);
  m.duty[1] = r.integer<std::uint16_t>(kDutyB);
  m.duty[2] = r.integer<std::uint16_t>(kDutyC);
  m.enable = r.boolean(kEnable);
}

static_assert(sensor_sample::kPwmPeriod.factor == kPwmPeriodStep_us &&
                  sensor_sample::kPwmPeriod.raw_max() == kPwmPeriodMaxCode,
              "SENSOR_SAMPLE PwmPeriod and SensorSample::pwm_period_code must agree (messages.hpp)");

void write_body(Writer& w, const SensorSample& m) noexcept {
  using namespace sensor_sample;
  w.raw(kSequence, m.sequence);
  w.raw(kPhaseCurrentAdcA, m.phase_current_adc[0]);
  w.raw(kPhaseCurrentAdcB, m.phase_current_adc[1]);
  w.raw(kPhaseCurrentAdcC, m.phase_current_adc[2]);
  w.raw(kEncoderCount, m.encoder_count);
  w.raw(kDcBusAdc, m.dc_bus_adc);
  w.raw(kPhaseVoltageAdcA, m.phase_voltage_adc[0]);
  w.raw(kPhaseVoltageAdcB, m.phase_voltage_adc[1]);
  w.raw(kPhaseVoltageAdcC, m.phase_voltage_adc[2]);
  w.boolean(kOutputEnabled, (m.flags & kSensorOutputEnabled) != 0U);
  w.boolean(kPhaseVoltageValid, (m.flags & kSensorPhaseVoltageValid) != 0U);
  w.boolean(kHardwareOvercurrent, (m.flags & kSensorHardwareOvercurrent) != 0U);
  const bool ambient = (m.flags & kSensorAmbientValid) != 0U;
  w.boolean(kAmbientValid, ambient);
  w.code_or_none(kPwmPeriod, m.pwm_period_code);
  w.raw(kAmbientTemp, ambient ? m.ambient_centi_C : 0);
}
void read_body(const Reader& r, SensorSample& m) noexcept {
  using namespace sensor_sample;
  m.sequence = r.integer<std::uint32_t>(kSequence);
  m.phase_current_adc[0] = r.integer<std::int16_t>(kPhaseCurrentAdcA);
  m.phase_current_adc[1] = r.integer<std::int16_t>(kPhaseCurrentAdcB);
  m.phase_current_adc[2] = r.integer<std::int16_t>(kPhaseCurrentAdcC);
  m.encoder_count = r.integer<std::uint16_t>(kEncoderCount);
  m.dc_bus_adc = r.integer<std::uint16_t>(kDcBusAdc);
  m.phase_voltage_adc[0] = r.integer<std::int16_t>(kPhaseVoltageAdcA);
  m.phase_voltage_adc[1] = r.integer<std::int16_t>(kPhaseVoltageAdcB);
  m.phase_voltage_adc[2] = r.integer<std::int16_t>(kPhaseVoltageAdcC);
  std::uint8_t flags = 0;
  if (r.boolean(kOutputEnabled)) {
    flags |= kSensorOutputEnabled;
  }
  if (r.boolean(kPhaseVoltageValid)) {
    flags |= kSensorPhaseVoltageValid;
  }
  if (r.boolean(kHardwareOvercurrent)) {
    flags |= kSensorHardwareOvercurrent;
  }
  if (r.boolean(kAmbientValid)) {
    flags |= kSensorAmbientValid;
    m.ambient_centi_C = r.integer<std::int16_t>(kAmbientTemp);
  }
  m.flags = flags;
  m.pwm_period_code = r.integer<std::uint16_t>(kPwmPeriod);
}

void write_body(Writer& w, const DriveCommand& m) noexcept {
  using namespace drive_command;
  w.boolean(kEnable, m.enable);
  w.enumeration(kMode, m.mode);
  w.physical(kSpeedSetpoint, m.speed_setpoint_rad_s);
  w.physical(kTorqueSetpoint, m.torque_setpoint_Nm);
}
void read_body(const Reader& r, DriveCommand& m) noexcept {
  using namespace drive_command;
  m.enable = r.boolean(kEnable);
  m.mode = r.enumeration<DriveMode>(kMode);
  m.speed_setpoint_rad_s = r.physical(kSpeedSetpoint);
  m.torque_setpoint_Nm = r.physical(kTorqueSetpoint);
}

void write_body(Writer& w, const InjectionCommand& m) noexcept {
  using namespace injection_command;
  w.boolean(kRequestNow, m.request_now);
  w.enumeration(kMethod, m.method);
  w.physical(kAmplitude, m.amplitude_A);
  w.physical(kInterval, m.interval_s);
}
void read_body(const Reader& r, InjectionCommand& m) noexcept {
  using namespace injection_command;
  m.request_now = r.boolean(kRequestNow);
  m.method = r.enumeration<InjectionMethod>(kMethod);
  m.amplitude_A = r.physical(kAmplitude);
  m.interval_s = r.physical(kInterval);
}

void write_body(Writer& w, const CalibrationCommand& m) noexcept {
  using namespace calibration_command;
  w.enumeration(kAction, m.action);
  w.physical(kKnownTemp, m.known_temp_C);
}
void read_body(const Reader& r, CalibrationCommand& m) noexcept {
  using namespace calibration_command;
  m.action = r.enumeration<CalibrationAction>(kAction);
  m.known_temp_C = r.physical(kKnownTemp);
}

void write_body(Writer& w, const FaultReport& m) noexcept {
  using namespace fault;
  w.enumeration(kCode, m.code);
  w.boolean(kActive, m.active);
  w.saturating(kOccurrenceCount, m.occurrence_count);
  w.physical(kLastChangeUptime, m.last_change_uptime_s);
}
void read_body(const Reader& r, FaultReport& m) noexcept {
  using namespace fault;
  m.code = r.enumeration<FaultCode>(kCode);
  m.active = r.boolean(kActive);
  m.occurrence_count = r.integer<std::uint32_t>(kOccurrenceCount);
  m.last_change_uptime_s = r.physical(kLastChangeUptime);
}

void write_body(Writer& w, const DriveStatus& m) noexcept {
  using namespace drive_status;
  w.enumeration(kState, m.state);
  w.boolean(kLimitWindingTemp, (m.limiting_reasons & kLimitReasonWindingTemp) != 0U);
  w.boolean(kLimitMagnetTemp, (m.limiting_reasons & kLimitReasonMagnetTemp) != 0U);
  w.boolean(kLimitVoltage, (m.limiting_reasons & kLimitReasonVoltage) != 0U);
  w.boolean(kLimitCurrent, (m.limiting_reasons & kLimitReasonCurrent) != 0U);
  w.boolean(kLimitSpeed, (m.limiting_reasons & kLimitReasonSpeed) != 0U);
  w.physical(kCurrentLimit, m.current_limit_A);
  w.guarded(kTimeToLimit, m.time_to_limit_valid, m.time_to_limit_s);
  w.boolean(kMotionValid, m.motion_valid);
  w.boolean(kTimeToLimitValid, m.time_to_limit_valid);
  w.guarded(kSpeed, m.motion_valid, m.speed_rad_s);
  w.guarded(kTorque, m.motion_valid, m.torque_Nm);
}
void read_body(const Reader& r, DriveStatus& m) noexcept {
  using namespace drive_status;
  m.state = r.enumeration<DriveState>(kState);
  std::uint8_t reasons = 0;
  if (r.boolean(kLimitWindingTemp)) {
    reasons |= kLimitReasonWindingTemp;
  }
  if (r.boolean(kLimitMagnetTemp)) {
    reasons |= kLimitReasonMagnetTemp;
  }
  if (r.boolean(kLimitVoltage)) {
    reasons |= kLimitReasonVoltage;
  }
  if (r.boolean(kLimitCurrent)) {
    reasons |= kLimitReasonCurrent;
  }
  if (r.boolean(kLimitSpeed)) {
    reasons |= kLimitReasonSpeed;
  }
  m.limiting_reasons = reasons;
  m.current_limit_A = r.physical(kCurrentLimit);
  m.time_to_limit_valid = r.boolean(kTimeToLimitValid);
  m.time_to_limit_s = r.guarded(kTimeToLimit, m.time_to_limit_valid);
  m.motion_valid = r.boolean(kMotionValid);
  m.speed_rad_s = r.guarded(kSpeed, m.motion_valid);
  m.torque_Nm = r.guarded(kTorque, m.motion_valid);
}

void write_body(Writer& w, const ThermalEstimate& m) noexcept {
  using namespace thermal_estimate;
  w.guarded(kWindingTemp, m.valid, m.winding_temp_C);
  w.guarded(kWindingTempSigma, m.valid, m.winding_temp_sigma_C);
  w.guarded(kMagnetTemp, m.magnet_valid, m.magnet_temp_C);
  w.boolean(kValid, m.valid);
  w.boolean(kCalibrated, m.calibrated);
  w.boolean(kDeratingActive, m.derating_active);
  w.boolean(kStale, m.stale);
  w.boolean(kMagnetValid, m.magnet_valid);
  w.enumeration(kCalibrationResult, m.calibration_result);
  w.boolean(kCalibrating, m.calibrating);
  w.guarded(kMagnetTempSigma, m.magnet_valid, m.magnet_temp_sigma_C);
}
void read_body(const Reader& r, ThermalEstimate& m) noexcept {
  using namespace thermal_estimate;
  m.valid = r.boolean(kValid);
  m.magnet_valid = r.boolean(kMagnetValid);
  m.winding_temp_C = r.guarded(kWindingTemp, m.valid);
  m.winding_temp_sigma_C = r.guarded(kWindingTempSigma, m.valid);
  m.magnet_temp_C = r.guarded(kMagnetTemp, m.magnet_valid);
  m.magnet_temp_sigma_C = r.guarded(kMagnetTempSigma, m.magnet_valid);
  m.calibrated = r.boolean(kCalibrated);
  m.derating_active = r.boolean(kDeratingActive);
  m.stale = r.boolean(kStale);
  m.calibration_result = r.enumeration<CalibrationResult>(kCalibrationResult);
  m.calibrating = r.boolean(kCalibrating);
}

void write_body(Writer& w, const ResistanceEstimate& m) noexcept {
  using namespace resistance_estimate;
  w.guarded(kRs, m.valid, m.rs_ohm);
  w.guarded(kRsSigma, m.valid, m.rs_sigma_ohm);
  w.physical(kRs0, m.rs0_ohm);
  w.boolean(kValid, m.valid);
  w.wrapping(kEstimateCount, m.estimate_count);
}
void read_body(const Reader& r, ResistanceEstimate& m) noexcept {
  using namespace resistance_estimate;
  m.valid = r.boolean(kValid);
  m.rs_ohm = r.guarded(kRs, m.valid);
  m.rs_sigma_ohm = r.guarded(kRsSigma, m.valid);
  m.rs0_ohm = r.physical(kRs0);
  m.estimate_count = r.integer<std::uint16_t>(kEstimateCount);
}

void write_body(Writer& w, const InjectionReport& m) noexcept {
  using namespace injection_report;
  w.wrapping(kInjectionCount, m.injection_count);
  w.enumeration(kMethod, m.method);
  w.enumeration(kResult, m.result);
  w.boolean(kRsValid, m.rs_valid);
  w.physical(kAmplitude, m.amplitude_A);
  w.guarded(kMeasuredRs, m.rs_valid, m.measured_rs_ohm);
  w.boolean(kSpeedChangeValid, m.speed_change_valid);
  w.guarded(kSpeedChange, m.speed_change_valid, m.speed_change_rad_s);
}
void read_body(const Reader& r, InjectionReport& m) noexcept {
  using namespace injection_report;
  m.injection_count = r.integer<std::uint8_t>(kInjectionCount);
  m.method = r.enumeration<InjectionMethod>(kMethod);
  m.result = r.enumeration<InjectionResult>(kResult);
  m.rs_valid = r.boolean(kRsValid);
  m.amplitude_A = r.physical(kAmplitude);
  m.measured_rs_ohm = r.guarded(kMeasuredRs, m.rs_valid);
  m.speed_change_valid = r.boolean(kSpeedChangeValid);
  m.speed_change_rad_s = r.guarded(kSpeedChange, m.speed_change_valid);
}

void write_body(Writer& w, const Heartbeat& m) noexcept {
  using namespace heartbeat;
  w.physical(kUptime, m.uptime_s);
  w.enumeration(kState, m.state);
  w.enumeration(kAmbientSource, m.ambient_source);
  w.wrapping(kCounter, m.counter);
  w.saturating(kDeadlineMisses, m.deadline_misses);
}
void read_body(const Reader& r, Heartbeat& m) noexcept {
  using namespace heartbeat;
  m.uptime_s = r.physical(kUptime);
  m.state = r.enumeration<DriveState>(kState);
  m.ambient_source = r.enumeration<AmbientSource>(kAmbientSource);
  m.counter = r.integer<std::uint8_t>(kCounter);
  m.deadline_misses = r.integer<std::uint32_t>(kDeadlineMisses);
}

void write_body(Writer& w, const ReceiveStatus& m) noexcept {
  using namespace receive_status;
  w.saturating(kLastRejection, m.last_rejection);
  w.saturating(kLastRejectedId, m.last_rejected_id);
  w.wrapping(kCommandsAccepted, m.commands_accepted);
  w.wrapping(kRejectedCrc, m.rejected_crc);
  w.wrapping(kRejectedCounter, m.rejected_counter);
  w.wrapping(kRejectedRange, m.rejected_range);
  w.wrapping(kRejectedFormat, m.rejected_format);
  w.wrapping(kRejectedOther, m.rejected_other);
}
void read_body(const Reader& r, ReceiveStatus& m) noexcept {
  using namespace receive_status;
  m.last_rejection = r.integer<std::uint8_t>(kLastRejection);
  m.last_rejected_id = r.integer<std::uint16_t>(kLastRejectedId);
  m.commands_accepted = r.integer<std::uint64_t>(kCommandsAccepted);
  m.rejected_crc = r.integer<std::uint64_t>(kRejectedCrc);
  m.rejected_counter = r.integer<std::uint64_t>(kRejectedCounter);
  m.rejected_range = r.integer<std::uint64_t>(kRejectedRange);
  m.rejected_format = r.integer<std::uint64_t>(kRejectedFormat);
  m.rejected_other = r.integer<std::uint64_t>(kRejectedOther);
}

void write_body(Writer& w, const LoopTiming& m) noexcept {
  using namespace loop_timing;
  w.physical(kLatencyP50, m.latency_p50_us);
  w.physical(kLatencyP99, m.latency_p99_us);
  w.physical(kLatencyMax, m.latency_max_us);
  w.saturating(kPeriods, m.periods);
  w.saturating(kDeadlineMisses, m.deadline_misses);
}
void read_body(const Reader& r, LoopTiming& m) noexcept {
  using namespace loop_timing;
  m.latency_p50_us = r.physical(kLatencyP50);
  m.latency_p99_us = r.physical(kLatencyP99);
  m.latency_max_us = r.physical(kLatencyMax);
  m.periods = r.integer<std::uint32_t>(kPeriods);
  m.deadline_misses = r.integer<std::uint32_t>(kDeadlineMisses);
}

void write_body(Writer& w, const TruthThermal& m) noexcept {
  using namespace truth_thermal;
  w.physical(kWindingTemp, m.winding_temp_C);
  w.physical(kHousingTemp, m.housing_temp_C);
  w.physical(kMagnetTemp, m.magnet_temp_C);
  w.physical(kAmbientTemp, m.ambient_temp_C);
}
void read_body(const Reader& r, TruthThermal& m) noexcept {
  using namespace truth_thermal;
  m.winding_temp_C = r.physical(kWindingTemp);
  m.housing_temp_C = r.physical(kHousingTemp);
  m.magnet_temp_C = r.physical(kMagnetTemp);
  m.ambient_temp_C = r.physical(kAmbientTemp);
}

void write_body(Writer& w, const TruthElectrical& m) noexcept {
  using namespace truth_electrical;
  w.physical(kRs, m.rs_ohm);
  w.physical(kSpeed, m.speed_rad_s);
  w.physical(kTorque, m.torque_Nm);
  w.physical(kLoadTorque, m.load_torque_Nm);
}
void read_body(const Reader& r, TruthElectrical& m) noexcept {
  using namespace truth_electrical;
  m.rs_ohm = r.physical(kRs);
  m.speed_rad_s = r.physical(kSpeed);
  m.torque_Nm = r.physical(kTorque);
  m.load_torque_Nm = r.physical(kLoadTorque);
}

void write_body(Writer& w, const PlantStatus& m) noexcept {
  using namespace plant_status;
  w.enumeration(kMode, m.mode);
  w.boolean(kOutputEnabled, m.output_enabled);
  w.boolean(kCommandTimeoutTripped, m.command_timeout_tripped);
  w.saturating(kLateCommands, m.late_commands);
  w.saturating(kMissingCommands, m.missing_commands);
  w.physical(kSimulatedTime, m.simulated_time_s);
}
void read_body(const Reader& r, PlantStatus& m) noexcept {
  using namespace plant_status;
  m.mode = r.enumeration<PlantMode>(kMode);
  m.output_enabled = r.boolean(kOutputEnabled);
  m.command_timeout_tripped = r.boolean(kCommandTimeoutTripped);
  m.late_commands = r.integer<std::uint32_t>(kLateCommands);
  m.missing_commands = r.integer<std::uint32_t>(kMissingCommands);
  m.simulated_time_s = r.physical(kSimulatedTime);
}

// ---------------------------------------------------------------------------------------
// Generic encode / decode
// ---------------------------------------------------------------------------------------

void start_frame(const MessageDef& def, NodeId node, CanFrame& out) noexcept {
  out = CanFrame{};
  out.id = def.can_id(node);
  out.fd = def.fd;
  out.length = def.length;
}

std::uint8_t frame_crc(const CanFrame& frame) noexcept {
  return e2e_crc(frame.id, std::span<const std::uint8_t, 8>(frame.data.data(), 8));
}

template <class T>
EncodeStatus encode_message(const T& message, NodeId node, CanFrame& out) noexcept {
  if (node > kMaxNodeId) {
    return EncodeStatus::kInvalidNode;
  }
  const MessageDef& def = def_of<T>();
  start_frame(def, node, out);
  Writer w(out);
  write_body(w, message);
  return w.status();
}

template <class T>
EncodeStatus encode_command(const T& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept {
  if (node > kMaxNodeId) {
    return EncodeStatus::kInvalidNode;
  }
  const MessageDef& def = def_of<T>();
  static_assert(def_of<T>().e2e && def_of<T>().length == 8);
  start_frame(def, node, out);
  Writer w(out);
  write_body(w, message);
  w.wrapping(e2e::kAliveCounter, alive_counter);
  out.data[e2e::kCrcByte] = frame_crc(out);
  return w.status();
}

// Identity, format, length and CRC; for any node when `node` is empty.
DecodeStatus check_frame(const CanFrame& frame, const MessageDef& def, std::optional<NodeId> node) noexcept {
  if (frame.error || frame.extended || (frame.id & ~kNodeIdMask) != def.id_base) {
    return DecodeStatus::kUnknownId;
  }
  if (node && node_of(frame.id) != *node) {
    return DecodeStatus::kWrongNode;
  }
  if (frame.fd != def.fd) {
    return DecodeStatus::kWrongFrameFormat;
  }
  if (frame.length != def.length) {
    return DecodeStatus::kWrongLength;
  }
  if (def.e2e && frame.data[e2e::kCrcByte] != frame_crc(frame)) {
    return DecodeStatus::kBadCrc;
  }
  return DecodeStatus::kOk;
}

// The raw bounds of every range-checked signal of a message, computed at compile time so
// that reception does no floating-point arithmetic for the check.
struct RawBounds {
  const SignalDef* signal;
  std::int64_t min;
  std::int64_t max;
};

template <class T>
constexpr std::size_t range_checked_count() {
  std::size_t n = 0;
  for (const SignalDef& s : def_of<T>().signals) {
    n += s.range_checked() ? 1U : 0U;
  }
  return n;
}

template <class T>
constexpr std::array<RawBounds, range_checked_count<T>()> make_bounds() {
  std::array<RawBounds, range_checked_count<T>()> bounds{};
  std::size_t i = 0;
  for (const SignalDef& s : def_of<T>().signals) {
    if (s.range_checked()) {
      bounds[i++] = RawBounds{&s, s.raw_min(), s.raw_max()};
    }
  }
  return bounds;
}

template <class T>
inline constexpr auto kBounds = make_bounds<T>();

// Range check and extraction, after check_frame (and the counter check) passed.
template <class T>
DecodeStatus decode_body(const CanFrame& frame, T& out) noexcept {
  const Reader r(frame);
  for (const RawBounds& b : kBounds<T>) {
    const std::int64_t raw = r.raw(*b.signal);
    if (raw < b.min || raw > b.max) {
      return DecodeStatus::kOutOfRange;
    }
  }
  read_body(r, out);
  return DecodeStatus::kOk;
}

// The fast-loop frames need no range check: every signal spans its type.
static_assert(range_checked_count<InverterCommand>() == 0);
static_assert(range_checked_count<SensorSample>() == 0);

template <class T>
DecodeStatus decode_message(const CanFrame& frame, std::optional<NodeId> node, T& out) noexcept {
  const DecodeStatus status = check_frame(frame, def_of<T>(), node);
  if (status != DecodeStatus::kOk) {
    return status;
  }
  return decode_body(frame, out);
}

std::uint8_t alive_counter_of(const CanFrame& frame) noexcept {
  return static_cast<std::uint8_t>(frame.data[1] & e2e::kCounterMask);
}

template <class T>
DecodeStatus decode_command(const CanFrame& frame, std::optional<NodeId> node, T& out,
                            std::uint8_t& alive_counter) noexcept {
  const DecodeStatus status = check_frame(frame, def_of<T>(), node);
  if (status != DecodeStatus::kOk) {
    return status;
  }
  alive_counter = alive_counter_of(frame);
  return decode_body(frame, out);
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Public functions
// ---------------------------------------------------------------------------------------

std::string_view to_string(EncodeStatus status) noexcept {
  switch (status) {
    case EncodeStatus::kOk: return "ok";
    case EncodeStatus::kSaturated: return "saturated";
    case EncodeStatus::kInvalidValue: return "invalid_value";
    case EncodeStatus::kInvalidNode: return "invalid_node";
  }
  return "unknown";
}

std::string_view to_string(DecodeStatus status) noexcept {
  switch (status) {
    case DecodeStatus::kOk: return "ok";
    case DecodeStatus::kUnknownId: return "unknown_id";
    case DecodeStatus::kWrongNode: return "wrong_node";
    case DecodeStatus::kWrongFrameFormat: return "wrong_frame_format";
    case DecodeStatus::kWrongLength: return "wrong_length";
    case DecodeStatus::kBadCrc: return "bad_crc";
    case DecodeStatus::kRepeatedCounter: return "repeated_counter";
    case DecodeStatus::kCounterJump: return "counter_jump";
    case DecodeStatus::kOutOfRange: return "out_of_range";
    case DecodeStatus::kStreamDisturbed: return "stream_disturbed";
  }
  return "unknown";
}

std::string_view describe(DecodeStatus status) noexcept {
  switch (status) {
    case DecodeStatus::kOk: return "Accepted.";
    case DecodeStatus::kUnknownId:
      return "Not a protocol ID, not a message this role receives, an extended-ID frame or an error frame.";
    case DecodeStatus::kWrongNode: return "A protocol message for another node id.";
    case DecodeStatus::kWrongFrameFormat: return "Classic CAN where the message is CAN FD, or vice versa.";
    case DecodeStatus::kWrongLength: return "Data length differs from the message's length.";
    case DecodeStatus::kBadCrc: return "Command frame whose CRC-8 (byte 0) does not match.";
    case DecodeStatus::kRepeatedCounter: return "Command frame repeating the last accepted alive counter.";
    case DecodeStatus::kCounterJump:
      return "Alive counter advanced by more than the allowed delta (frames lost, or a stale frame); the stream re-synchronises on it.";
    case DecodeStatus::kOutOfRange: return "A signal lies outside its [min, max].";
    case DecodeStatus::kStreamDisturbed:
      return "A command that passed its checks, not acted on: two frames of its stream failed their CRC, length or format within the last 1 s (a stop, or a repeat of the last drive command, is acted on).";
  }
  return "";
}

std::uint8_t e2e_crc(std::uint32_t can_id, std::span<const std::uint8_t, 8> payload) noexcept {
  Crc8SaeJ1850 crc;
  crc.update(static_cast<std::uint8_t>(can_id & 0xFFU));
  crc.update(static_cast<std::uint8_t>((can_id >> 8U) & 0xFFU));
  crc.update(payload.subspan<1>());
  return crc.value();
}

AliveCounterCheck::AliveCounterCheck(std::uint8_t max_delta) noexcept
    : max_delta_(std::clamp<std::uint8_t>(max_delta, 1, kAliveCounterModulo - 2)) {}

DecodeStatus AliveCounterCheck::check(std::uint8_t counter) noexcept {
  counter = static_cast<std::uint8_t>(counter % kAliveCounterModulo);
  if (!synchronized_) {
    synchronized_ = true;
    last_ = counter;
    return DecodeStatus::kOk;
  }
  const auto delta = static_cast<std::uint8_t>((counter + kAliveCounterModulo - last_) % kAliveCounterModulo);
  if (delta == 0) {
    return DecodeStatus::kRepeatedCounter;
  }
  last_ = counter;
  return delta <= max_delta_ ? DecodeStatus::kOk : DecodeStatus::kCounterJump;
}

EncodeStatus encode(const InverterCommand& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const SensorSample& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, InverterCommand& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, SensorSample& out) noexcept {
  return decode_message(frame, node, out);
}

EncodeStatus encode(const DriveCommand& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept {
  return encode_command(message, node, alive_counter, out);
}
EncodeStatus encode(const InjectionCommand& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept {
  return encode_command(message, node, alive_counter, out);
}
EncodeStatus encode(const CalibrationCommand& message, NodeId node, std::uint8_t alive_counter, CanFrame& out) noexcept {
  return encode_command(message, node, alive_counter, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, DriveCommand& out, std::uint8_t& alive_counter) noexcept {
  return decode_command(frame, node, out, alive_counter);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, InjectionCommand& out, std::uint8_t& alive_counter) noexcept {
  return decode_command(frame, node, out, alive_counter);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, CalibrationCommand& out, std::uint8_t& alive_counter) noexcept {
  return decode_command(frame, node, out, alive_counter);
}

EncodeStatus encode(const FaultReport& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const DriveStatus& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const ThermalEstimate& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const ResistanceEstimate& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const InjectionReport& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const Heartbeat& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const ReceiveStatus& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const LoopTiming& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const TruthThermal& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const TruthElectrical& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
EncodeStatus encode(const PlantStatus& message, NodeId node, CanFrame& out) noexcept {
  return encode_message(message, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, FaultReport& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, DriveStatus& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, ThermalEstimate& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, ResistanceEstimate& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, InjectionReport& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, Heartbeat& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, ReceiveStatus& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, LoopTiming& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, TruthThermal& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, TruthElectrical& out) noexcept {
  return decode_message(frame, node, out);
}
DecodeStatus decode(const CanFrame& frame, NodeId node, PlantStatus& out) noexcept {
  return decode_message(frame, node, out);
}

TruthThermal truth_thermal_from(const TruthSample& truth, double ambient_temp_C) noexcept {
  return {static_cast<double>(truth.winding_temp_C), static_cast<double>(truth.housing_temp_C),
          static_cast<double>(truth.magnet_temp_C), ambient_temp_C};
}

TruthElectrical truth_electrical_from(const TruthSample& truth) noexcept {
  return {static_cast<double>(truth.rs_ohm), static_cast<double>(truth.speed_rad_s),
          static_cast<double>(truth.torque_Nm), static_cast<double>(truth.load_torque_Nm)};
}

// ---------------------------------------------------------------------------------------
// decode_any
// ---------------------------------------------------------------------------------------

namespace {

template <class T>
DecodeStatus decode_any_as(const CanFrame& frame, AnyDecoded& out) noexcept {
  T message{};
  std::uint8_t counter = 0;
  DecodeStatus status = DecodeStatus::kOk;
  if constexpr (def_of<T>().e2e) {
    status = decode_command(frame, std::nullopt, message, counter);
  } else {
    status = decode_message(frame, std::nullopt, message);
  }
  if (status == DecodeStatus::kOk || (def_of<T>().e2e && status == DecodeStatus::kOutOfRange)) {
    out.type = kTypeOf<T>;
    out.node = node_of(frame.id);
    out.message = message;
    out.alive_counter = counter;
  }
  return status;
}

template <std::size_t... I>
constexpr bool variant_matches_message_types(std::index_sequence<I...> /*unused*/) {
  return ((kTypeOf<std::variant_alternative_t<I, AnyMessage>> == static_cast<MessageType>(I)) && ...);
}
static_assert(std::variant_size_v<AnyMessage> == kMessageCount);
static_assert(variant_matches_message_types(std::make_index_sequence<kMessageCount>{}));

}  // namespace

DecodeStatus decode_any(const CanFrame& frame, AnyDecoded& out) noexcept {
  if (frame.error || frame.extended) {
    return DecodeStatus::kUnknownId;
  }
  const MessageDef* def = find_message(frame.id);
  if (def == nullptr) {
    return DecodeStatus::kUnknownId;
  }
  switch (def->type) {
    case MessageType::kInverterCommand: return decode_any_as<InverterCommand>(frame, out);
    case MessageType::kSensorSample: return decode_any_as<SensorSample>(frame, out);
    case MessageType::kDriveCommand: return decode_any_as<DriveCommand>(frame, out);
    case MessageType::kInjectionCommand: return decode_any_as<InjectionCommand>(frame, out);
    case MessageType::kCalibrationCommand: return decode_any_as<CalibrationCommand>(frame, out);
    case MessageType::kFault: return decode_any_as<FaultReport>(frame, out);
    case MessageType::kDriveStatus: return decode_any_as<DriveStatus>(frame, out);
    case MessageType::kThermalEstimate: return decode_any_as<ThermalEstimate>(frame, out);
    case MessageType::kResistanceEstimate: return decode_any_as<ResistanceEstimate>(frame, out);
    case MessageType::kInjectionReport: return decode_any_as<InjectionReport>(frame, out);
    case MessageType::kHeartbeat: return decode_any_as<Heartbeat>(frame, out);
    case MessageType::kReceiveStatus: return decode_any_as<ReceiveStatus>(frame, out);
    case MessageType::kLoopTiming: return decode_any_as<LoopTiming>(frame, out);
    case MessageType::kTruthThermal: return decode_any_as<TruthThermal>(frame, out);
    case MessageType::kTruthElectrical: return decode_any_as<TruthElectrical>(frame, out);
    case MessageType::kPlantStatus: return decode_any_as<PlantStatus>(frame, out);
  }
  return DecodeStatus::kUnknownId;
}

// ---------------------------------------------------------------------------------------
// Receivers and sender
// ---------------------------------------------------------------------------------------

DaemonReceiver::DaemonReceiver(NodeId node, std::uint8_t max_counter_delta) noexcept
    : node_(node),
      streams_{AliveCounterCheck(max_counter_delta), AliveCounterCheck(max_counter_delta),
               AliveCounterCheck(max_counter_delta)} {}

const DecodeCounters& DaemonReceiver::counters(MessageType type) const noexcept {
  return per_type_[static_cast<std::size_t>(type)];
}

std::optional<std::chrono::nanoseconds> DaemonReceiver::last_accepted(MessageType type) const noexcept {
  return last_accepted_[static_cast<std::size_t>(type)];
}

std::optional<std::chrono::nanoseconds> DaemonReceiver::age(MessageType type,
                                                            std::chrono::nanoseconds now) const noexcept {
  const auto& last = last_accepted_[static_cast<std::size_t>(type)];
  if (!last) {
    return std::nullopt;
  }
  return now - *last;
}

void DaemonReceiver::resync(CommandStream stream) noexcept {
  streams_[static_cast<std::size_t>(stream)].reset();
}

std::array<std::uint8_t, 7> DaemonReceiver::drive_command_payload(const CanFrame& frame) noexcept {
  std::array<std::uint8_t, 7> payload{};
  std::copy_n(frame.data.begin() + 1, payload.size(), payload.begin());
  payload[0] = static_cast<std::uint8_t>(payload[0] & ~e2e::kCounterMask);
  return payload;
}

bool DaemonReceiver::disturbed(CommandStream stream, std::chrono::nanoseconds now) const noexcept {
  const IntegrityErrors& e = integrity_errors_[static_cast<std::size_t>(stream)];
  // The ring's next slot holds the oldest of the last kDisturbedErrors failures.
  return e.count >= kDisturbedErrors && now - e.at[e.count % kDisturbedErrors] < kDisturbedWindow;
}

DaemonInput DaemonReceiver::reject(const CanFrame& frame, const MessageDef* def, DecodeStatus reason) noexcept {
  total_.count(reason);
  if (def != nullptr) {
    per_type_[static_cast<std::size_t>(def->type)].count(reason);
  }
  return Rejected{reason, frame.id};
}

void DaemonReceiver::accept(MessageType type, std::chrono::nanoseconds now) noexcept {
  total_.count(DecodeStatus::kOk);
  per_type_[static_cast<std::size_t>(type)].count(DecodeStatus::kOk);
  last_accepted_[static_cast<std::size_t>(type)] = now;
}

namespace {
// A command that can only take the drive towards its safe state: acted on even from a disturbed
// stream (a garbage frame that passes as one costs a stop, never a start).
bool towards_safe_state(const DriveCommand& c) noexcept { return !c.enable || c.mode == DriveMode::kDisabled; }
bool towards_safe_state(const InjectionCommand&) noexcept { return false; }
bool towards_safe_state(const CalibrationCommand& c) noexcept { return c.action != CalibrationAction::kStart; }
}  // namespace

template <class Command>
DaemonInput DaemonReceiver::receive_command(const CanFrame& frame, CommandStream stream,
                                            std::chrono::nanoseconds now) noexcept {
  const MessageDef& def = def_of<Command>();
  DecodeStatus status = check_frame(frame, def, node_);
  if (status == DecodeStatus::kBadCrc || status == DecodeStatus::kWrongLength ||
      status == DecodeStatus::kWrongFrameFormat) {
    IntegrityErrors& e = integrity_errors_[static_cast<std::size_t>(stream)];
    e.at[e.count % kDisturbedErrors] = now;
    ++e.count;
  }
  if (status != DecodeStatus::kOk) {
    return reject(frame, &def, status);
  }
  // The E2E check (CRC, then counter) comes before the application's range check, as in
  // AUTOSAR: a genuine frame with a bad value still advances the stream.
  status = streams_[static_cast<std::size_t>(stream)].check(alive_counter_of(frame));
  if (status != DecodeStatus::kOk) {
    return reject(frame, &def, status);
  }
  Command command{};
  status = decode_body(frame, command);
  if (status != DecodeStatus::kOk) {
    return reject(frame, &def, status);
  }
  // No new order: a stop, or a DRIVE_COMMAND that repeats the last one acted on.
  bool no_new_order = towards_safe_state(command);
  if constexpr (std::is_same_v<Command, DriveCommand>) {
    no_new_order = no_new_order || drive_command_payload(frame) == last_drive_command_;
  }
  if (!no_new_order && disturbed(stream, now)) {
    return reject(frame, &def, DecodeStatus::kStreamDisturbed);
  }
  if constexpr (std::is_same_v<Command, DriveCommand>) {
    last_drive_command_ = drive_command_payload(frame);
  }
  accept(def.type, now);
  return command;
}

DaemonInput DaemonReceiver::receive(const CanFrame& frame, std::chrono::nanoseconds now) noexcept {
  const MessageDef* def = (frame.error || frame.extended) ? nullptr : find_message(frame.id);
  if (def == nullptr || !def->received_by(Role::kDaemon)) {
    return reject(frame, nullptr, DecodeStatus::kUnknownId);
  }
  switch (def->type) {
    case MessageType::kSensorSample: {
      SensorSample sample{};
      const DecodeStatus status = decode_message(frame, node_, sample);
      if (status != DecodeStatus::kOk) {
        return reject(frame, def, status);
      }
      accept(def->type, now);
      return sample;
    }
    case MessageType::kDriveCommand:
      return receive_command<DriveCommand>(frame, CommandStream::kDrive, now);
    case MessageType::kInjectionCommand:
      return receive_command<InjectionCommand>(frame, CommandStream::kInjection, now);
    case MessageType::kCalibrationCommand:
      return receive_command<CalibrationCommand>(frame, CommandStream::kCalibration, now);
    default:
      return reject(frame, nullptr, DecodeStatus::kUnknownId);
  }
}

PlantInput PlantReceiver::receive(const CanFrame& frame) noexcept {
  InverterCommand command{};
  const DecodeStatus status = decode_message(frame, node_, command);
  counters_.count(status);
  if (status != DecodeStatus::kOk) {
    return Rejected{status, frame.id};
  }
  return command;
}

void CommandSender::advance(CommandStream stream, EncodeStatus status) noexcept {
  // Only a frame that may be sent takes the counter: a saturated command is not sent
  // (docs/protocol.md), and a counter it took would make the next command a jump, which the
  // drive refuses (found by a review, 2026-12-05).
  if (status == EncodeStatus::kOk) {
    auto& counter = counters_[static_cast<std::size_t>(stream)];
    counter = static_cast<std::uint8_t>((counter + 1U) % kAliveCounterModulo);
  }
}

EncodeStatus CommandSender::encode(const DriveCommand& message, CanFrame& out) noexcept {
  const EncodeStatus status = protocol::encode(message, node_, next_counter(CommandStream::kDrive), out);
  advance(CommandStream::kDrive, status);
  return status;
}

EncodeStatus CommandSender::encode(const InjectionCommand& message, CanFrame& out) noexcept {
  const EncodeStatus status = protocol::encode(message, node_, next_counter(CommandStream::kInjection), out);
  advance(CommandStream::kInjection, status);
  return status;
}

EncodeStatus CommandSender::encode(const CalibrationCommand& message, CanFrame& out) noexcept {
  const EncodeStatus status = protocol::encode(message, node_, next_counter(CommandStream::kCalibration), out);
  advance(CommandStream::kCalibration, status);
  return status;
}

}  // namespace pmsm::hal::protocol
