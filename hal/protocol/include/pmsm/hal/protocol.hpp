// The pmsm-thermal CAN protocol: the ONE definition of every frame and signal (DESIGN §6).
//
// Everything else is derived from the tables below: the typed codec (codec.hpp), the DBC
// file can/pmsm-thermal.dbc (pmsm-dbc-gen, dbc_writer.hpp), the frame tables in
// docs/protocol.md, and the kernel receive filters (protocol_filters.hpp). Tests parse the
// generated DBC with an independent reader (dbc.hpp) and check that it decodes what the
// codec encodes; a change here without regenerating the committed files fails a test.
//
// Conventions (see docs/protocol.md for the full text):
//   - 11-bit identifiers, ID = id_base + node_id, node_id 0..15, so every base is a multiple
//     of 0x10. Lower ID = higher priority: fast loop, then commands, then faults, then
//     telemetry, then the bench (truth) frames.
//   - All signals little-endian (Intel, DBC "@1"); start_bit is the LSB's position, bit k
//     of the payload being bit (k % 8) of byte (k / 8). Reserved bits are sent as 0 and
//     ignored on reception.
//   - physical = raw * factor + offset. A received raw value outside [minimum, maximum]
//     (converted to raw) rejects the frame (DecodeStatus::kOutOfRange).
//   - Command frames (e2e = true) carry an AUTOSAR-E2E-profile-1-like protection: byte 0 is
//     a CRC-8 SAE J1850 over the 11-bit CAN ID (low byte, then high byte) followed by
//     payload bytes 1..7; the low nibble of byte 1 is a 4-bit alive counter.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

namespace pmsm::hal::protocol {

// ---------------------------------------------------------------------------------------
// Identifiers and roles
// ---------------------------------------------------------------------------------------

using NodeId = std::uint8_t;
inline constexpr NodeId kMaxNodeId = 15;
inline constexpr std::uint32_t kNodeIdMask = 0x00F;  // the node-id bits of a CAN ID
inline constexpr std::uint32_t kIdBaseMask = 0x7F0;  // the message bits of a CAN ID

// Protocol version, written into the DBC's VERSION line. Bump it on any layout change.
inline constexpr std::string_view kProtocolVersion = "pmsm-thermal-can 1.7";

// The parties on the bus (DBC "BU_" nodes). A receive-filter role is one of these.
enum class Role : std::uint8_t {
  kDaemon,      // pmsm-thermald: the drive controller
  kPlant,       // pmsm-plant: the motor/inverter emulator (or the real power stage)
  kSupervisor,  // whoever commands the drive (PLC, vehicle controller, test script)
  kMonitor,     // a passive watcher or test bench: telemetry and ground truth
};
inline constexpr std::size_t kRoleCount = 4;

[[nodiscard]] constexpr std::uint8_t role_bit(Role role) noexcept {
  return static_cast<std::uint8_t>(1U << static_cast<unsigned>(role));
}

struct RoleDef {
  Role role;
  std::string_view name;      // for logs and docs
  std::string_view dbc_name;  // DBC node name
  std::string_view comment;
};

inline constexpr std::array<RoleDef, kRoleCount> kRoles{{
    {Role::kDaemon, "daemon", "THERMALD", "pmsm-thermald, the drive controller with the winding-temperature estimator."},
    {Role::kPlant, "plant", "PLANT", "pmsm-plant, the motor, inverter and sensor emulator (or the real power stage)."},
    {Role::kSupervisor, "supervisor", "SUPERVISOR", "The party that commands the drive: PLC, vehicle controller or test script."},
    {Role::kMonitor, "monitor", "MONITOR", "A passive watcher or test bench: telemetry and ground truth, never sends."},
}};

// Every message type, in ID order. The value indexes kMessages.
enum class MessageType : std::uint8_t {
  kInverterCommand,
  kSensorSample,
  kDriveCommand,
  kInjectionCommand,
  kCalibrationCommand,
  kFault,
  kDriveStatus,
  kThermalEstimate,
  kResistanceEstimate,
  kInjectionReport,
  kHeartbeat,
  kReceiveStatus,
  kLoopTiming,
  kTruthThermal,
  kTruthElectrical,
  kPlantStatus,
};
inline constexpr std::size_t kMessageCount = 16;

// ---------------------------------------------------------------------------------------
// Definition types
// ---------------------------------------------------------------------------------------

struct ValueLabel {
  std::int64_t value;
  std::string_view label;
};

// The label of `value` in a value table ("?" if it has none).
[[nodiscard]] constexpr std::string_view label_of(std::span<const ValueLabel> labels, std::int64_t value) noexcept {
  for (const ValueLabel& l : labels) {
    if (l.value == value) {
      return l.label;
    }
  }
  return "?";
}

struct SignalDef {
  std::string_view name;       // DBC signal name (CamelCase)
  std::uint16_t start_bit;     // LSB position, little-endian bit numbering
  std::uint8_t length;         // bits, 1..32
  bool is_signed;              // two's complement
  double factor;
  double offset;
  double minimum;              // physical
  double maximum;              // physical
  std::string_view unit;       // ASCII (DBC files are not UTF-8)
  std::span<const ValueLabel> values;  // value table, empty if none
  std::string_view comment;

  // The raw range the type can hold.
  [[nodiscard]] constexpr std::int64_t type_raw_min() const noexcept {
    return is_signed ? -(std::int64_t{1} << (length - 1U)) : 0;
  }
  [[nodiscard]] constexpr std::int64_t type_raw_max() const noexcept {
    return is_signed ? (std::int64_t{1} << (length - 1U)) - 1 : (std::int64_t{1} << length) - 1;
  }
  // [minimum, maximum] converted to raw (minimum and maximum lie on the raw grid; a
  // compile-time check in protocol.cpp proves it for every signal).
  [[nodiscard]] constexpr std::int64_t raw_min() const noexcept { return round_raw(minimum); }
  [[nodiscard]] constexpr std::int64_t raw_max() const noexcept { return round_raw(maximum); }
  // Whether the declared range is narrower than the type (so reception must check it).
  [[nodiscard]] constexpr bool range_checked() const noexcept {
    return raw_min() > type_raw_min() || raw_max() < type_raw_max();
  }
  [[nodiscard]] constexpr double raw_to_physical(std::int64_t raw) const noexcept {
    return static_cast<double>(raw) * factor + offset;
  }

 private:
  [[nodiscard]] constexpr std::int64_t round_raw(double physical) const noexcept {
    const double raw = (physical - offset) / factor;
    return raw >= 0.0 ? static_cast<std::int64_t>(raw + 0.5) : -static_cast<std::int64_t>(-raw + 0.5);
  }
};

struct MessageDef {
  MessageType type;
  std::string_view name;       // DBC message name (UPPER_SNAKE)
  std::uint16_t id_base;       // ID for node 0; ID = id_base + node_id
  std::uint8_t length;         // bytes
  bool fd;                     // CAN FD frame (else classic CAN 2.0)
  Role sender;
  std::uint8_t receivers;      // role_bit() mask
  bool e2e;                    // CRC-8 in byte 0, alive counter in byte 1 bits 0..3
  std::uint16_t cycle_time_ms; // nominal period; 0 = every control period or on event
  std::string_view timing;     // when it is sent, in words (docs)
  std::span<const SignalDef> signals;
  std::string_view comment;

  [[nodiscard]] constexpr std::uint32_t can_id(NodeId node) const noexcept {
    return std::uint32_t{id_base} + (std::uint32_t{node} & kNodeIdMask);
  }
  [[nodiscard]] constexpr bool received_by(Role role) const noexcept {
    return (receivers & role_bit(role)) != 0U;
  }
};

// ---------------------------------------------------------------------------------------
// Value tables (enum values are the raw signal values)
// ---------------------------------------------------------------------------------------

enum class DriveMode : std::uint8_t { kDisabled = 0, kTorque = 1, kSpeed = 2 };
inline constexpr std::array<ValueLabel, 3> kDriveModeLabels{{
    {0, "DISABLED"}, {1, "TORQUE"}, {2, "SPEED"}}};

enum class InjectionMethod : std::uint8_t {
  kOff = 0,
  kFixedMagnitudeBipolar = 1,
  kFixedMagnitudeUnipolar = 2,
  kFixedAngleBipolar = 3,
  kFixedAngleUnipolar = 4,
  kDc = 5,
};
inline constexpr std::array<ValueLabel, 6> kInjectionMethodLabels{{
    {0, "OFF"},
    {1, "FIXED_MAGNITUDE_BIPOLAR"},
    {2, "FIXED_MAGNITUDE_UNIPOLAR"},
    {3, "FIXED_ANGLE_BIPOLAR"},
    {4, "FIXED_ANGLE_UNIPOLAR"},
    {5, "DC"}}};

enum class CalibrationAction : std::uint8_t { kNone = 0, kStart = 1, kAbort = 2 };
inline constexpr std::array<ValueLabel, 3> kCalibrationActionLabels{{
    {0, "NONE"}, {1, "START"}, {2, "ABORT"}}};

// How the last Rs0 calibration run ended, since the daemon started.
enum class CalibrationResult : std::uint8_t {
  kNone = 0,      // none has ended since start, or one is running (or suspended by a fault)
  kDone = 1,      // completed: its Rs0 is in use (and stored, where the daemon has a file)
  kAborted = 2,   // stopped by an ABORT command (a fault or disabling the drive only suspends it)
  kTimedOut = 3,  // too few accepted measurements within calibration.timeout_s
  kRefused = 4,   // Rs0 less certain than calibration.max_rs0_std_fraction (the bridge's voltage not learned)
};
inline constexpr std::array<ValueLabel, 5> kCalibrationResultLabels{{
    {0, "NONE"}, {1, "DONE"}, {2, "ABORTED"}, {3, "TIMED_OUT"}, {4, "REFUSED"}}};

// Where the thermal model's ambient / coolant boundary comes from (HEARTBEAT AmbientSource).
enum class AmbientSource : std::uint8_t {
  kConfigured = 0,  // no sensor reading: the configured ambient
  kSensor = 1,      // the power stage's sensor (SENSOR_SAMPLE AmbientTemp)
  kHeld = 2,        // the sensor stopped reporting: its last reading, held
};
inline constexpr std::array<ValueLabel, 3> kAmbientSourceLabels{{{0, "CONFIGURED"}, {1, "SENSOR"}, {2, "HELD"}}};

enum class DriveState : std::uint8_t {
  kInit = 0,         // starting up, checks not yet passed; gates off
  kStandby = 1,      // ready, gates off (not enabled, or mode DISABLED)
  kRunning = 2,      // gates on, torque or speed control
  kCalibrating = 3,  // Rs0 calibration in progress
  kFault = 4,        // safe state: zero voltage, gate enable low (see FAULT frames)
};
inline constexpr std::array<ValueLabel, 5> kDriveStateLabels{{
    {0, "INIT"}, {1, "STANDBY"}, {2, "RUNNING"}, {3, "CALIBRATING"}, {4, "FAULT"}}};

// Bits of DriveStatus::limiting_reasons. Limiting reasons say why the drive gives less than
// was asked; they are not faults (faults are latched and published in FAULT frames).
enum LimitReason : std::uint8_t {
  kLimitReasonWindingTemp = 1U << 0,  // current limit derated for winding temperature
  kLimitReasonMagnetTemp = 1U << 1,   // current limit derated for magnet temperature
  kLimitReasonVoltage = 1U << 2,      // voltage limit (DC bus) reached
  kLimitReasonCurrent = 1U << 3,      // (derated) current limit reached
  kLimitReasonSpeed = 1U << 4,        // speed limit reached
};

enum class InjectionResult : std::uint8_t {
  kAccepted = 0,
  kRejectedSpeedChange = 1,     // speed changed too much between the two recordings
  kRejectedLoadChange = 2,      // load (iqr) changed too much between the recordings
  kRejectedResidual = 3,        // the separation left too large a residual
  kRejectedVoltageHeadroom = 4, // not enough voltage for the injection (Eq. 29)
  kRejectedCurrentLimit = 5,    // injection would exceed the (derated) current limit
  kRejectedImplausible = 6,     // resistance outside its plausibility window
  kRejectedVoltageSaturation = 7,  // the bridge may not have applied a recorded command (not the loop's voltage limit alone)
  kRejectedIllConditioned = 8,  // too few samples or collinear regressors
  kAborted = 9,                 // interrupted (disable, fault, mode change)
  kSkippedTorqueDisturbance = 10,  // the injection would move the torque too much (saliency)
};
// The same numbering as core::PairOutcome (a test checks it).
inline constexpr std::array<ValueLabel, 11> kInjectionResultLabels{{
    {0, "ACCEPTED"},
    {1, "REJECTED_SPEED_CHANGE"},
    {2, "REJECTED_LOAD_CHANGE"},
    {3, "REJECTED_RESIDUAL"},
    {4, "REJECTED_VOLTAGE_HEADROOM"},
    {5, "REJECTED_CURRENT_LIMIT"},
    {6, "REJECTED_IMPLAUSIBLE"},
    {7, "REJECTED_VOLTAGE_SATURATION"},
    {8, "REJECTED_ILL_CONDITIONED"},
    {9, "ABORTED"},
    {10, "SKIPPED_TORQUE_DISTURBANCE"}}};

enum class FaultCode : std::uint8_t {
  kNone = 0,
  kSensorTimeout = 1,        // sensor frames missing for N periods
  kOvercurrent = 2,          // software over-current
  kOvertemperature = 3,      // winding (or magnet) temperature above the trip limit
  kBusOff = 4,               // CAN controller bus-off
  kInterfaceDown = 5,        // CAN interface down or gone
  kCommandTimeout = 6,       // no valid, fresh command within the command timeout
  kGpioFault = 7,            // GPIO fault input asserted or GPIO access failed
  kConfig = 8,               // invalid configuration
  kHardwareOvercurrent = 9,  // the power stage's own comparator tripped
  kDeadlineOverrun = 10,     // the control loop missed too many deadlines
  kCalibrationFailed = 11,   // Rs0 calibration failed
  kStorage = 12,             // persisting calibration failed
  kInternal = 13,            // the controller could not compute a finite command
  kDcBusUndervoltage = 14,   // DC bus below its window
  kDcBusOvervoltage = 15,    // DC bus above its window
  kInputNotFinite = 16,      // NaN or infinity in a measurement
  kEncoderJump = 17,         // the angle moved more in one period than the speed limit allows
  kCurrentSum = 18,          // |ia + ib + ic| too large: a phase-current sensor is broken
  kAmbientImplausible = 19,  // the ambient / coolant sensor reads outside its window
  kOverspeed = 20,           // the shaft turned faster than the overspeed limit
  kPeriodMismatch = 21,      // the power stage samples at another period than the drive's
  kCurrentOffset = 22,       // a current sensor read far from zero with the gates off at power-up
  kOutputFeedback = 23,      // the power stage kept its gates off while the drive enabled them
  kDuplicateNode = 24,       // another sender transmits this node's daemon frames, or its samples
};
inline constexpr std::size_t kFaultCodeCount = 25;
inline constexpr std::array<ValueLabel, kFaultCodeCount> kFaultCodeLabels{{
    {0, "NONE"},
    {1, "SENSOR_TIMEOUT"},
    {2, "OVERCURRENT"},
    {3, "OVERTEMPERATURE"},
    {4, "BUS_OFF"},
    {5, "INTERFACE_DOWN"},
    {6, "COMMAND_TIMEOUT"},
    {7, "GPIO_FAULT"},
    {8, "CONFIG"},
    {9, "HARDWARE_OVERCURRENT"},
    {10, "DEADLINE_OVERRUN"},
    {11, "CALIBRATION_FAILED"},
    {12, "STORAGE"},
    {13, "INTERNAL"},
    {14, "DC_BUS_UNDERVOLTAGE"},
    {15, "DC_BUS_OVERVOLTAGE"},
    {16, "INPUT_NOT_FINITE"},
    {17, "ENCODER_JUMP"},
    {18, "CURRENT_SUM"},
    {19, "AMBIENT_IMPLAUSIBLE"},
    {20, "OVERSPEED"},
    {21, "PERIOD_MISMATCH"},
    {22, "CURRENT_OFFSET"},
    {23, "OUTPUT_FEEDBACK"},
    {24, "DUPLICATE_NODE"}}};

enum class PlantMode : std::uint8_t { kRealtime = 0, kLockstep = 1 };
inline constexpr std::array<ValueLabel, 2> kPlantModeLabels{{{0, "REALTIME"}, {1, "LOCKSTEP"}}};

// ---------------------------------------------------------------------------------------
// Typed messages (physical values, units in the names). The fast-loop frames use the plain
// types of messages.hpp (SensorSample, InverterCommand).
// Fields guarded by a validity bit are encoded as raw 0 when the bit is clear and decoded
// as NaN then, so that "no value" never looks like a plausible number.
// ---------------------------------------------------------------------------------------

struct DriveCommand {
  bool enable = false;
  DriveMode mode = DriveMode::kDisabled;
  double speed_setpoint_rad_s = 0.0;   // mechanical, used in SPEED mode
  double torque_setpoint_Nm = 0.0;     // used in TORQUE mode
};

struct InjectionCommand {
  InjectionMethod method = InjectionMethod::kOff;
  double amplitude_A = 0.0;            // injection amplitude F (peak, rotor-frame d axis)
  double interval_s = 0.0;             // time between injections; 0: only on request
  bool request_now = false;            // one injection as soon as possible
};

struct CalibrationCommand {
  CalibrationAction action = CalibrationAction::kNone;
  double known_temp_C = 0.0;           // the winding's temperature now (motor at rest, soaked)
};

struct FaultReport {
  FaultCode code = FaultCode::kNone;
  bool active = false;                 // false: the fault has cleared (report kept for history)
  std::uint32_t occurrence_count = 0;  // since start; saturates at 65535 on the bus
  double last_change_uptime_s = 0.0;   // daemon uptime when it last became active or cleared
};

struct DriveStatus {
  DriveState state = DriveState::kInit;
  std::uint8_t limiting_reasons = 0;   // LimitReason bits
  double current_limit_A = 0.0;        // present (derated) current-amplitude limit
  bool time_to_limit_valid = false;
  double time_to_limit_s = 0.0;        // until the winding reaches its derating threshold
  bool motion_valid = false;           // guards speed_rad_s and torque_Nm: the drive tracks the shaft
  double speed_rad_s = 0.0;            // mechanical
  double torque_Nm = 0.0;              // estimated electromagnetic torque incl. reluctance
};

struct ThermalEstimate {
  bool valid = false;                  // guards winding_temp_C and winding_temp_sigma_C
  double winding_temp_C = 0.0;
  double winding_temp_sigma_C = 0.0;   // 1-sigma uncertainty
  bool magnet_valid = false;           // guards magnet_temp_C and magnet_temp_sigma_C
  double magnet_temp_C = 0.0;
  double magnet_temp_sigma_C = 0.0;    // 1-sigma uncertainty (saturates at 31.75 on the wire)
  bool calibrated = false;             // Rs0 comes from a calibration, not the default
  bool derating_active = false;
  bool stale = false;                  // no accepted resistance measurement recently
  // The last calibration run's outcome: a refused or timed-out one leaves the calibration in
  // use (Calibrated says whether that is a calibration or the configured default).
  CalibrationResult calibration_result = CalibrationResult::kNone;
  bool calibrating = false;            // a calibration run is in progress
};

struct ResistanceEstimate {
  bool valid = false;                  // guards rs_ohm and rs_sigma_ohm
  double rs_ohm = 0.0;                 // phase-to-neutral
  double rs_sigma_ohm = 0.0;           // 1-sigma; saturates at 81.91 mOhm on the bus
  double rs0_ohm = 0.0;                // reference resistance at the calibration temperature
  std::uint16_t estimate_count = 0;    // accepted estimates, modulo 1024 on the bus
};

struct InjectionReport {
  std::uint8_t injection_count = 0;    // wraps at 256
  InjectionMethod method = InjectionMethod::kOff;
  InjectionResult result = InjectionResult::kAborted;
  double amplitude_A = 0.0;            // F used (a skipped pair: the largest the budget allowed)
  bool rs_valid = false;               // guards measured_rs_ohm
  double measured_rs_ohm = 0.0;
  bool speed_change_valid = false;     // guards speed_change_rad_s: both recordings have samples
  double speed_change_rad_s = 0.0;     // mechanical speed change between the recordings
};

struct Heartbeat {
  double uptime_s = 0.0;
  DriveState state = DriveState::kInit;
  std::uint8_t counter = 0;            // +1 per heartbeat, wraps
  std::uint32_t deadline_misses = 0;   // since start; saturates at 65535 on the bus
  AmbientSource ambient_source = AmbientSource::kConfigured;
};

// What the daemon did with the frames addressed to it (commands and sensor samples): counts
// since start by reason, each sent modulo 256 (a watcher takes differences), and the last
// rejection. The reasons are the codec's DecodeStatus values (a test checks the labels).
struct ReceiveStatus {
  std::uint8_t last_rejection = 0;        // DecodeStatus of the last rejected frame (0: none yet)
  std::uint16_t last_rejected_id = 0;     // its CAN ID
  std::uint64_t commands_accepted = 0;    // drive + injection + calibration commands acted on
  std::uint64_t rejected_crc = 0;         // bad CRC
  std::uint64_t rejected_counter = 0;     // repeated alive counter or a jump (stale, lost, replayed)
  std::uint64_t rejected_range = 0;       // a signal out of its range
  std::uint64_t rejected_format = 0;      // wrong length or frame format
  std::uint64_t rejected_other = 0;       // unknown ID, another node's frame
};

// The control loop's sample -> command latency over the last window (one HEARTBEAT period),
// from the loop's log2-bucket histogram: the percentiles are the upper bounds of the buckets
// holding them, the maximum is exact.
struct LoopTiming {
  double latency_p50_us = 0.0;
  double latency_p99_us = 0.0;
  double latency_max_us = 0.0;
  std::uint32_t periods = 0;              // commands sent in the window (saturates at 65535 on the bus)
  std::uint32_t deadline_misses = 0;      // in the window (saturates at 255 on the bus)
};

struct TruthThermal {
  double winding_temp_C = 0.0;
  double housing_temp_C = 0.0;
  double magnet_temp_C = 0.0;
  double ambient_temp_C = 0.0;
};

struct TruthElectrical {
  double rs_ohm = 0.0;
  double speed_rad_s = 0.0;
  double torque_Nm = 0.0;
  double load_torque_Nm = 0.0;
};

struct PlantStatus {
  PlantMode mode = PlantMode::kRealtime;
  bool output_enabled = false;
  bool command_timeout_tripped = false;
  std::uint32_t late_commands = 0;     // saturates at 65535 on the bus
  std::uint32_t missing_commands = 0;  // saturates at 65535 on the bus
  double simulated_time_s = 0.0;
};

// ---------------------------------------------------------------------------------------
// Signal tables, one namespace per message
// ---------------------------------------------------------------------------------------

namespace detail {
inline constexpr std::span<const ValueLabel> kNoValues{};
inline constexpr double kDutyFactor = 1.0 / 65535.0;
}  // namespace detail

// Common E2E header of every command frame.
namespace e2e {
inline constexpr SignalDef kCrc{"Crc", 0, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xor 0xFF) over the CAN ID (low byte, high byte) and bytes 1..7."};
inline constexpr SignalDef kAliveCounter{"AliveCounter", 8, 4, false, 1, 0, 0, 15, "", detail::kNoValues,
    "Alive counter, +1 (mod 16) per frame of this command stream."};
inline constexpr std::size_t kCrcByte = 0;
inline constexpr std::uint8_t kCounterMask = 0x0F;  // in byte 1
}  // namespace e2e

namespace inverter_command {
inline constexpr SignalDef kSequence{"Sequence", 0, 32, false, 1, 0, 0, 4294967295.0, "", detail::kNoValues,
    "Sequence of the sensor sample this command was computed from; applied in the next period."};
inline constexpr SignalDef kDutyA{"DutyA", 32, 16, false, detail::kDutyFactor, 0, 0, 1, "", detail::kNoValues,
    "Phase a high-side on-time fraction (raw 0..65535 = 0..1)."};
inline constexpr SignalDef kDutyB{"DutyB", 48, 16, false, detail::kDutyFactor, 0, 0, 1, "", detail::kNoValues,
    "Phase b high-side on-time fraction (raw 0..65535 = 0..1)."};
inline constexpr SignalDef kDutyC{"DutyC", 64, 16, false, detail::kDutyFactor, 0, 0, 1, "", detail::kNoValues,
    "Phase c high-side on-time fraction (raw 0..65535 = 0..1)."};
inline constexpr SignalDef kEnable{"Enable", 80, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: gates switch; 0: all gates off (coast, safe torque off)."};
inline constexpr std::array<SignalDef, 5> kSignals{kSequence, kDutyA, kDutyB, kDutyC, kEnable};
}  // namespace inverter_command

namespace sensor_sample {
inline constexpr SignalDef kSequence{"Sequence", 0, 32, false, 1, 0, 0, 4294967295.0, "", detail::kNoValues,
    "Period index k; sampled at the start of period k."};
inline constexpr SignalDef kPhaseCurrentAdcA{"PhaseCurrentAdcA", 32, 16, true, 1, 0, -32768, 32767, "", detail::kNoValues,
    "Phase a current, signed ADC code about mid-scale."};
inline constexpr SignalDef kPhaseCurrentAdcB{"PhaseCurrentAdcB", 48, 16, true, 1, 0, -32768, 32767, "", detail::kNoValues,
    "Phase b current, signed ADC code about mid-scale."};
inline constexpr SignalDef kPhaseCurrentAdcC{"PhaseCurrentAdcC", 64, 16, true, 1, 0, -32768, 32767, "", detail::kNoValues,
    "Phase c current, signed ADC code about mid-scale."};
inline constexpr SignalDef kEncoderCount{"EncoderCount", 80, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "Absolute mechanical angle, 0 .. 2^bits - 1."};
inline constexpr SignalDef kDcBusAdc{"DcBusAdc", 96, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "DC-bus voltage, unsigned ADC code."};
inline constexpr SignalDef kPhaseVoltageAdcA{"PhaseVoltageAdcA", 112, 16, true, 1, 0, -32768, 32767, "", detail::kNoValues,
    "Phase a to neutral voltage, signed ADC code (valid if PhaseVoltageValid)."};
inline constexpr SignalDef kPhaseVoltageAdcB{"PhaseVoltageAdcB", 128, 16, true, 1, 0, -32768, 32767, "", detail::kNoValues,
    "Phase b to neutral voltage, signed ADC code (valid if PhaseVoltageValid)."};
inline constexpr SignalDef kPhaseVoltageAdcC{"PhaseVoltageAdcC", 144, 16, true, 1, 0, -32768, 32767, "", detail::kNoValues,
    "Phase c to neutral voltage, signed ADC code (valid if PhaseVoltageValid)."};
inline constexpr SignalDef kOutputEnabled{"OutputEnabled", 160, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "The inverter's gates are switching."};
inline constexpr SignalDef kPhaseVoltageValid{"PhaseVoltageValid", 161, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "The PhaseVoltageAdc signals hold measurements."};
inline constexpr SignalDef kHardwareOvercurrent{"HardwareOvercurrent", 162, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "The power stage's own over-current comparator tripped."};
inline constexpr SignalDef kAmbientValid{"AmbientValid", 163, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "AmbientTemp holds a reading of the drive's ambient / coolant sensor."};
inline constexpr SignalDef kPwmPeriod{"PwmPeriod", 164, 12, false, 0.25, 0, 0, 1023.75, "us", detail::kNoValues,
    "The power stage's PWM period, at which it samples (0: not reported); the drive faults (PERIOD_MISMATCH) "
    "when it is not its controller.control.period_s."};
inline constexpr SignalDef kAmbientTemp{"AmbientTemp", 176, 16, true, 0.01, 0, -327.68, 327.67, "degC", detail::kNoValues,
    "The drive's ambient / coolant temperature sensor (valid if AmbientValid): the thermal model's boundary."};
inline constexpr std::array<SignalDef, 15> kSignals{
    kSequence, kPhaseCurrentAdcA, kPhaseCurrentAdcB, kPhaseCurrentAdcC, kEncoderCount, kDcBusAdc,
    kPhaseVoltageAdcA, kPhaseVoltageAdcB, kPhaseVoltageAdcC, kOutputEnabled, kPhaseVoltageValid,
    kHardwareOvercurrent, kAmbientValid, kPwmPeriod, kAmbientTemp};
}  // namespace sensor_sample

namespace drive_command {
inline constexpr SignalDef kEnable{"Enable", 12, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: enable the drive; 0: gates off."};
inline constexpr SignalDef kMode{"Mode", 13, 2, false, 1, 0, 0, 2, "", kDriveModeLabels,
    "Control mode; 3 is out of range."};
inline constexpr SignalDef kSpeedSetpoint{"SpeedSetpoint", 16, 24, true, 0.001, 0, -2000, 2000, "rad/s", detail::kNoValues,
    "Mechanical speed setpoint (SPEED mode)."};
inline constexpr SignalDef kTorqueSetpoint{"TorqueSetpoint", 40, 24, true, 0.001, 0, -1000, 1000, "Nm", detail::kNoValues,
    "Torque setpoint (TORQUE mode)."};
inline constexpr std::array<SignalDef, 6> kSignals{
    e2e::kCrc, e2e::kAliveCounter, kEnable, kMode, kSpeedSetpoint, kTorqueSetpoint};
}  // namespace drive_command

namespace injection_command {
inline constexpr SignalDef kRequestNow{"RequestNow", 12, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: perform one injection as soon as the operating point allows."};
inline constexpr SignalDef kMethod{"Method", 16, 8, false, 1, 0, 0, 5, "", kInjectionMethodLabels,
    "Injection and separation method (paper: fixed-magnitude / fixed-angle, bipolar / unipolar; DC baseline)."};
inline constexpr SignalDef kAmplitude{"Amplitude", 24, 16, false, 0.01, 0, 0, 300, "A", detail::kNoValues,
    "Injection amplitude F (peak d-axis current); 0: the drive keeps its configured F."};
inline constexpr SignalDef kInterval{"Interval", 40, 16, false, 0.1, 0, 0, 6000, "s", detail::kNoValues,
    "Time between injections; 0: injections only on request."};
inline constexpr std::array<SignalDef, 6> kSignals{
    e2e::kCrc, e2e::kAliveCounter, kRequestNow, kMethod, kAmplitude, kInterval};
}  // namespace injection_command

namespace calibration_command {
inline constexpr SignalDef kAction{"Action", 12, 2, false, 1, 0, 0, 2, "", kCalibrationActionLabels,
    "START: calibrate Rs0 at KnownTemp now; ABORT: stop a running calibration."};
inline constexpr SignalDef kKnownTemp{"KnownTemp", 16, 16, true, 0.01, 0, -40, 150, "degC", detail::kNoValues,
    "Known winding temperature (motor soaked at this temperature)."};
inline constexpr std::array<SignalDef, 4> kSignals{e2e::kCrc, e2e::kAliveCounter, kAction, kKnownTemp};
}  // namespace calibration_command

namespace fault {
inline constexpr SignalDef kCode{"Code", 0, 8, false, 1, 0, 0, 24, "", kFaultCodeLabels, "Fault code."};
inline constexpr SignalDef kActive{"Active", 8, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: the fault is active; 0: it has cleared."};
inline constexpr SignalDef kOccurrenceCount{"OccurrenceCount", 16, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "Times this fault became active since start (saturates)."};
inline constexpr SignalDef kLastChangeUptime{"LastChangeUptime", 32, 32, false, 0.01, 0, 0, 42949672.95, "s", detail::kNoValues,
    "Daemon uptime when the fault last became active or cleared."};
inline constexpr std::array<SignalDef, 4> kSignals{kCode, kActive, kOccurrenceCount, kLastChangeUptime};
}  // namespace fault

namespace drive_status {
inline constexpr SignalDef kState{"State", 0, 3, false, 1, 0, 0, 4, "", kDriveStateLabels, "Drive state."};
inline constexpr SignalDef kLimitWindingTemp{"LimitWindingTemp", 3, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "Limiting: current derated for winding temperature."};
inline constexpr SignalDef kLimitMagnetTemp{"LimitMagnetTemp", 4, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "Limiting: current derated for magnet temperature."};
inline constexpr SignalDef kLimitVoltage{"LimitVoltage", 5, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "Limiting: voltage limit reached."};
inline constexpr SignalDef kLimitCurrent{"LimitCurrent", 6, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "Limiting: current limit reached."};
inline constexpr SignalDef kLimitSpeed{"LimitSpeed", 7, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "Limiting: speed limit reached."};
inline constexpr SignalDef kCurrentLimit{"CurrentLimit", 8, 12, false, 0.1, 0, 0, 400, "A", detail::kNoValues,
    "Present (derated) current-amplitude limit."};
inline constexpr SignalDef kTimeToLimit{"TimeToLimit", 20, 13, false, 1, 0, 0, 8191, "s", detail::kNoValues,
    "Time until the winding reaches its derating threshold if the present load continues (saturates at 8191 s); see TimeToLimitValid."};
inline constexpr SignalDef kMotionValid{"MotionValid", 33, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: Speed and Torque are the drive's present reading; 0: none (no usable sensor sample: the power stage silent, a latched fault, the shaft's tracker restarting)."};
inline constexpr SignalDef kTimeToLimitValid{"TimeToLimitValid", 34, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: TimeToLimit holds a prediction; 0: none (not heating, or no estimate)."};
inline constexpr SignalDef kSpeed{"Speed", 35, 15, true, 0.2, 0, -3200, 3200, "rad/s", detail::kNoValues,
    "Mechanical speed (0.2 rad/s steps; beyond the set-point range, so that a shaft carried past it reads true)."};
inline constexpr SignalDef kTorque{"Torque", 50, 14, true, 0.05, 0, -400, 400, "Nm", detail::kNoValues,
    "Estimated electromagnetic torque, including reluctance torque: the mean over the frame's interval, at the magnets' flux as the drive knows it (the calibrated Ke0 at their estimated temperature)."};
inline constexpr std::array<SignalDef, 12> kSignals{
    kState, kLimitWindingTemp, kLimitMagnetTemp, kLimitVoltage, kLimitCurrent, kLimitSpeed,
    kCurrentLimit, kTimeToLimit, kMotionValid, kTimeToLimitValid, kSpeed, kTorque};
}  // namespace drive_status

namespace thermal_estimate {
inline constexpr SignalDef kWindingTemp{"WindingTemp", 0, 16, true, 0.01, 0, -50, 300, "degC", detail::kNoValues,
    "Estimated stator-winding temperature (0 when Valid is 0)."};
inline constexpr SignalDef kWindingTempSigma{"WindingTempSigma", 16, 16, false, 0.01, 0, 0, 500, "degC", detail::kNoValues,
    "1-sigma uncertainty of WindingTemp (0 when Valid is 0)."};
inline constexpr SignalDef kMagnetTemp{"MagnetTemp", 32, 16, true, 0.01, 0, -50, 300, "degC", detail::kNoValues,
    "Estimated magnet temperature from the EMF constant (0 when MagnetValid is 0)."};
inline constexpr SignalDef kValid{"Valid", 48, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: WindingTemp and WindingTempSigma hold an estimate."};
inline constexpr SignalDef kCalibrated{"Calibrated", 49, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: Rs0 comes from a calibration; 0: from the configured default."};
inline constexpr SignalDef kDeratingActive{"DeratingActive", 50, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: the current limit is derated for temperature, the winding's or the magnets' (DRIVE_STATUS's LimitWindingTemp and LimitMagnetTemp say which)."};
inline constexpr SignalDef kStale{"Stale", 51, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: no resistance measurement accepted recently; the estimate runs on the thermal model alone."};
inline constexpr SignalDef kMagnetValid{"MagnetValid", 52, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: MagnetTemp holds an estimate measured within calibration.magnet_max_age_s of thermal time."};
inline constexpr SignalDef kCalibrationResult{"CalibrationResult", 53, 3, false, 1, 0, 0, 4, "", kCalibrationResultLabels,
    "How the last calibration since start ended; ABORTED, TIMED_OUT and REFUSED keep the calibration in use."};
inline constexpr SignalDef kCalibrating{"Calibrating", 56, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: a calibration run is in progress (its result follows in CalibrationResult)."};
inline constexpr SignalDef kMagnetTempSigma{"MagnetTempSigma", 57, 7, false, 0.25, 0, 0, 31.75, "degC", detail::kNoValues,
    "1-sigma uncertainty of MagnetTemp, Ke0's included (saturates; 0 when MagnetValid is 0)."};
inline constexpr std::array<SignalDef, 11> kSignals{
    kWindingTemp, kWindingTempSigma, kMagnetTemp, kValid, kCalibrated, kDeratingActive, kStale, kMagnetValid,
    kCalibrationResult, kCalibrating, kMagnetTempSigma};
}  // namespace thermal_estimate

namespace resistance_estimate {
inline constexpr SignalDef kRs{"Rs", 0, 20, false, 0.00001, 0, 0, 10, "Ohm", detail::kNoValues,
    "Phase-to-neutral stator resistance of the last estimate the thermal filter accepted (one its plausibility gate refused is not sent; 0 when Valid is 0)."};
inline constexpr SignalDef kRsSigma{"RsSigma", 20, 13, false, 0.00001, 0, 0, 0.08191, "Ohm", detail::kNoValues,
    "1-sigma uncertainty of Rs (saturates; 0 when Valid is 0)."};
inline constexpr SignalDef kRs0{"Rs0", 33, 20, false, 0.00001, 0, 0, 10, "Ohm", detail::kNoValues,
    "Reference resistance at the calibration temperature."};
inline constexpr SignalDef kValid{"Valid", 53, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: Rs and RsSigma hold an estimate."};
inline constexpr SignalDef kEstimateCount{"EstimateCount", 54, 10, false, 1, 0, 0, 1023, "", detail::kNoValues,
    "Accepted resistance estimates (wraps at 1024)."};
inline constexpr std::array<SignalDef, 5> kSignals{kRs, kRsSigma, kRs0, kValid, kEstimateCount};
}  // namespace resistance_estimate

namespace injection_report {
inline constexpr SignalDef kInjectionCount{"InjectionCount", 0, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Injections attempted (wraps at 256)."};
inline constexpr SignalDef kMethod{"Method", 8, 3, false, 1, 0, 0, 5, "", kInjectionMethodLabels,
    "Method and separation of this pair: a calibration's pairs are its own procedure's (fixed-magnitude bipolar), whatever the run-time method."};
inline constexpr SignalDef kResult{"Result", 11, 4, false, 1, 0, 0, 10, "", kInjectionResultLabels,
    "Outcome of the injection."};
inline constexpr SignalDef kRsValid{"RsValid", 15, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: MeasuredRs holds this pair's measurement. 0: the pair was not accepted, or its Rs rests on the configured "
    "guess of the inverter's voltage (no event has learned it yet: a calibration's first pairs, and every pair of a "
    "drive where none does)."};
inline constexpr SignalDef kAmplitude{"Amplitude", 16, 12, false, 0.1, 0, 0, 400, "A", detail::kNoValues,
    "Injection amplitude F used; for a pair skipped by its budget, the largest the budget allowed (below the minimum)."};
inline constexpr SignalDef kMeasuredRs{"MeasuredRs", 28, 20, false, 0.00001, 0, 0, 10, "Ohm", detail::kNoValues,
    "Resistance measured by this pair, with the inverter's voltage as learned when it ended (0 when RsValid is 0); the "
    "estimate is RESISTANCE_ESTIMATE's, the event's fit over its pairs."};
inline constexpr SignalDef kSpeedChangeValid{"SpeedChangeValid", 48, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "1: SpeedChange holds a measurement; 0: none (the pair was aborted or skipped before both recordings had samples)."};
inline constexpr SignalDef kSpeedChange{"SpeedChange", 49, 15, true, 0.002, 0, -32.768, 32.766, "rad/s", detail::kNoValues,
    "Mechanical speed change between the two recordings (saturates; 0 when SpeedChangeValid is 0)."};
inline constexpr std::array<SignalDef, 8> kSignals{
    kInjectionCount, kMethod, kResult, kRsValid, kAmplitude, kMeasuredRs, kSpeedChangeValid, kSpeedChange};
}  // namespace injection_report

namespace heartbeat {
inline constexpr SignalDef kUptime{"Uptime", 0, 32, false, 0.01, 0, 0, 42949672.95, "s", detail::kNoValues,
    "Daemon uptime (saturates after 497 days)."};
inline constexpr SignalDef kState{"State", 32, 3, false, 1, 0, 0, 4, "", kDriveStateLabels, "Drive state."};
inline constexpr SignalDef kCounter{"Counter", 40, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "+1 per heartbeat (wraps)."};
inline constexpr SignalDef kDeadlineMisses{"DeadlineMisses", 48, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "Control-loop deadline misses since start (saturates)."};
inline constexpr SignalDef kAmbientSource{"AmbientSource", 35, 2, false, 1, 0, 0, 2, "", kAmbientSourceLabels,
    "Where the thermal model's ambient / coolant temperature comes from: the power stage's sensor, the configured value (no sensor reading), or the sensor's last reading held since it stopped reporting (a calibration at the ambient is then refused)."};
inline constexpr std::array<SignalDef, 5> kSignals{kUptime, kState, kAmbientSource, kCounter, kDeadlineMisses};
}  // namespace heartbeat

// The codec's DecodeStatus numbering (codec.hpp; a test checks the two agree).
inline constexpr std::array<ValueLabel, 10> kDecodeStatusLabels{{
    {0, "NONE"}, {1, "UNKNOWN_ID"}, {2, "WRONG_NODE"}, {3, "WRONG_FRAME_FORMAT"}, {4, "WRONG_LENGTH"},
    {5, "BAD_CRC"}, {6, "REPEATED_COUNTER"}, {7, "COUNTER_JUMP"}, {8, "OUT_OF_RANGE"}, {9, "STREAM_DISTURBED"}}};

namespace receive_status {
inline constexpr SignalDef kLastRejection{"LastRejection", 0, 4, false, 1, 0, 0, 9, "", kDecodeStatusLabels,
    "Why the last rejected frame was rejected (NONE: nothing rejected since start)."};
inline constexpr SignalDef kLastRejectedId{"LastRejectedId", 4, 11, false, 1, 0, 0, 2047, "", detail::kNoValues,
    "CAN ID of the last rejected frame."};
inline constexpr SignalDef kCommandsAccepted{"CommandsAccepted", 16, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Drive, injection and calibration commands acted on since start (modulo 256)."};
inline constexpr SignalDef kRejectedCrc{"RejectedCrc", 24, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Frames rejected for a bad CRC since start (modulo 256)."};
inline constexpr SignalDef kRejectedCounter{"RejectedCounter", 32, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Commands rejected for their alive counter (repeated: replayed or stale; jump: lost) since start (modulo 256)."};
inline constexpr SignalDef kRejectedRange{"RejectedRange", 40, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Frames rejected for a signal out of its range since start (modulo 256)."};
inline constexpr SignalDef kRejectedFormat{"RejectedFormat", 48, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Frames rejected for a wrong length or frame format since start (modulo 256)."};
inline constexpr SignalDef kRejectedOther{"RejectedOther", 56, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Frames rejected as unknown or another node's, and commands held back while their stream was disturbed, since start (modulo 256)."};
inline constexpr std::array<SignalDef, 8> kSignals{kLastRejection, kLastRejectedId, kCommandsAccepted, kRejectedCrc,
                                                   kRejectedCounter, kRejectedRange, kRejectedFormat, kRejectedOther};
}  // namespace receive_status

namespace loop_timing {
inline constexpr SignalDef kLatencyP50{"LatencyP50", 0, 12, false, 1, 0, 0, 4095, "us", detail::kNoValues,
    "Median sample -> command latency in the window: upper bound of its log2 bucket (saturates)."};
inline constexpr SignalDef kLatencyP99{"LatencyP99", 12, 12, false, 1, 0, 0, 4095, "us", detail::kNoValues,
    "99th percentile of the latency in the window: upper bound of its log2 bucket (saturates)."};
inline constexpr SignalDef kLatencyMax{"LatencyMax", 24, 16, false, 0.1, 0, 0, 6553.5, "us", detail::kNoValues,
    "Largest latency in the window (saturates)."};
inline constexpr SignalDef kPeriods{"Periods", 40, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "Commands sent in the window (saturates): the number of latencies behind the figures."};
inline constexpr SignalDef kDeadlineMisses{"DeadlineMisses", 56, 8, false, 1, 0, 0, 255, "", detail::kNoValues,
    "Latencies longer than one control period in the window (saturates)."};
inline constexpr std::array<SignalDef, 5> kSignals{kLatencyP50, kLatencyP99, kLatencyMax, kPeriods, kDeadlineMisses};
}  // namespace loop_timing

namespace truth_thermal {
inline constexpr SignalDef kWindingTemp{"WindingTemp", 0, 16, true, 0.01, 0, -327.68, 327.67, "degC", detail::kNoValues,
    "True winding temperature."};
inline constexpr SignalDef kHousingTemp{"HousingTemp", 16, 16, true, 0.01, 0, -327.68, 327.67, "degC", detail::kNoValues,
    "True stator iron / housing temperature."};
inline constexpr SignalDef kMagnetTemp{"MagnetTemp", 32, 16, true, 0.01, 0, -327.68, 327.67, "degC", detail::kNoValues,
    "True magnet temperature."};
inline constexpr SignalDef kAmbientTemp{"AmbientTemp", 48, 16, true, 0.01, 0, -327.68, 327.67, "degC", detail::kNoValues,
    "Ambient temperature."};
inline constexpr std::array<SignalDef, 4> kSignals{kWindingTemp, kHousingTemp, kMagnetTemp, kAmbientTemp};
}  // namespace truth_thermal

namespace truth_electrical {
inline constexpr SignalDef kRs{"Rs", 0, 20, false, 0.00001, 0, 0, 10.48575, "Ohm", detail::kNoValues,
    "True phase-to-neutral stator resistance."};
inline constexpr SignalDef kSpeed{"Speed", 20, 16, true, 0.1, 0, -3276.8, 3276.7, "rad/s", detail::kNoValues,
    "True mechanical speed."};
inline constexpr SignalDef kTorque{"Torque", 36, 14, true, 0.05, 0, -409.6, 409.55, "Nm", detail::kNoValues,
    "True electromagnetic torque, including reluctance torque."};
inline constexpr SignalDef kLoadTorque{"LoadTorque", 50, 14, true, 0.05, 0, -409.6, 409.55, "Nm", detail::kNoValues,
    "Torque applied by the load."};
inline constexpr std::array<SignalDef, 4> kSignals{kRs, kSpeed, kTorque, kLoadTorque};
}  // namespace truth_electrical

namespace plant_status {
inline constexpr SignalDef kMode{"Mode", 0, 1, false, 1, 0, 0, 1, "", kPlantModeLabels, "Plant time base."};
inline constexpr SignalDef kOutputEnabled{"OutputEnabled", 1, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "The emulated inverter's gates are switching."};
inline constexpr SignalDef kCommandTimeoutTripped{"CommandTimeoutTripped", 2, 1, false, 1, 0, 0, 1, "", detail::kNoValues,
    "The plant disabled its output because inverter commands stopped."};
inline constexpr SignalDef kLateCommands{"LateCommands", 8, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "Inverter commands that arrived after their period (saturates)."};
inline constexpr SignalDef kMissingCommands{"MissingCommands", 24, 16, false, 1, 0, 0, 65535, "", detail::kNoValues,
    "Periods without an inverter command (saturates)."};
inline constexpr SignalDef kSimulatedTime{"SimulatedTime", 40, 24, false, 0.01, 0, 0, 167772.15, "s", detail::kNoValues,
    "Simulated time since start (saturates)."};
inline constexpr std::array<SignalDef, 6> kSignals{
    kMode, kOutputEnabled, kCommandTimeoutTripped, kLateCommands, kMissingCommands, kSimulatedTime};
}  // namespace plant_status

// ---------------------------------------------------------------------------------------
// The message table, indexed by MessageType
// ---------------------------------------------------------------------------------------

namespace detail {
inline constexpr std::uint8_t kToDaemon = role_bit(Role::kDaemon);
inline constexpr std::uint8_t kToPlant = role_bit(Role::kPlant);
inline constexpr std::uint8_t kToWatchers = role_bit(Role::kSupervisor) | role_bit(Role::kMonitor);
inline constexpr std::uint8_t kToBench = role_bit(Role::kMonitor);
}  // namespace detail

inline constexpr std::array<MessageDef, kMessageCount> kMessages{{
    {MessageType::kInverterCommand, "INVERTER_COMMAND", 0x010, 12, true, Role::kDaemon, detail::kToPlant,
     false, 0, "every control period (10 kHz), after each SENSOR_SAMPLE", inverter_command::kSignals,
     "Fast loop: the controller's duty cycles for the next PWM period."},
    {MessageType::kSensorSample, "SENSOR_SAMPLE", 0x020, 24, true, Role::kPlant, detail::kToDaemon,
     false, 0, "every control period (10 kHz)", sensor_sample::kSignals,
     "Fast loop: one period's sensor readings as ADC codes and encoder counts."},
    {MessageType::kDriveCommand, "DRIVE_COMMAND", 0x040, 8, false, Role::kSupervisor, detail::kToDaemon,
     true, 20, "cyclic, 20 ms recommended; the daemon's command timeout applies", drive_command::kSignals,
     "Enable, control mode and setpoints. CRC and alive counter protected."},
    {MessageType::kInjectionCommand, "INJECTION_COMMAND", 0x050, 8, false, Role::kSupervisor, detail::kToDaemon,
     true, 0, "on change", injection_command::kSignals,
     "Injection method, amplitude, interval and one-shot request. CRC and alive counter protected."},
    {MessageType::kCalibrationCommand, "CALIBRATION_COMMAND", 0x060, 8, false, Role::kSupervisor, detail::kToDaemon,
     true, 0, "on request", calibration_command::kSignals,
     "Rs0 calibration at a known winding temperature. CRC and alive counter protected."},
    {MessageType::kFault, "FAULT", 0x080, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 0, "when a fault becomes active or clears; active faults repeated every 1 s", fault::kSignals,
     "One fault's state; faults are latched and kept apart from limiting reasons."},
    {MessageType::kDriveStatus, "DRIVE_STATUS", 0x100, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 100, "every 100 ms", drive_status::kSignals,
     "Drive state, limiting reasons, derated current limit, time to limit, speed and torque."},
    {MessageType::kThermalEstimate, "THERMAL_ESTIMATE", 0x110, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 100, "every 100 ms, and at once when Calibrating changes", thermal_estimate::kSignals,
     "Winding temperature estimate with its uncertainty, magnet temperature and status. A pmsm-plant with an "
     "accelerated thermal time also reads its node's Calibrating bit (real thermal time while it is set)."},
    {MessageType::kResistanceEstimate, "RESISTANCE_ESTIMATE", 0x120, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 1000, "every 1 s and after each accepted estimate", resistance_estimate::kSignals,
     "Stator resistance estimate, its uncertainty and Rs0."},
    {MessageType::kInjectionReport, "INJECTION_REPORT", 0x130, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 0, "after each injection attempt", injection_report::kSignals,
     "Outcome of one injection: method, result, F, measured Rs and speed change."},
    {MessageType::kHeartbeat, "HEARTBEAT", 0x140, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 1000, "every 1 s", heartbeat::kSignals,
     "Daemon liveness: uptime, state, counter, deadline misses."},
    {MessageType::kReceiveStatus, "RECEIVE_STATUS", 0x150, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 1000, "with every HEARTBEAT, and at most every 100 ms while frames are being rejected", receive_status::kSignals,
     "What the daemon did with the frames sent to it: commands accepted, rejections by reason, the last one."},
    {MessageType::kLoopTiming, "LOOP_TIMING", 0x160, 8, false, Role::kDaemon, detail::kToWatchers,
     false, 1000, "with every HEARTBEAT", loop_timing::kSignals,
     "Control-loop timing over the last HEARTBEAT period: sample -> command latency and deadline misses."},
    {MessageType::kTruthThermal, "TRUTH_THERMAL", 0x200, 8, false, Role::kPlant, detail::kToBench,
     false, 100, "every 100 ms (plant only, never read by the daemon)", truth_thermal::kSignals,
     "Plant ground truth: temperatures, as a bench's thermocouples would report them."},
    {MessageType::kTruthElectrical, "TRUTH_ELECTRICAL", 0x210, 8, false, Role::kPlant, detail::kToBench,
     false, 100, "every 100 ms (plant only, never read by the daemon)", truth_electrical::kSignals,
     "Plant ground truth: resistance, speed, torque and load torque."},
    {MessageType::kPlantStatus, "PLANT_STATUS", 0x220, 8, false, Role::kPlant, detail::kToBench,
     false, 100, "every 100 ms, with the truth frames", plant_status::kSignals,
     "Plant emulator status: time base, output, command timing."},
}};

[[nodiscard]] constexpr const MessageDef& message_def(MessageType type) noexcept {
  return kMessages[static_cast<std::size_t>(type)];
}

[[nodiscard]] constexpr std::uint32_t can_id(MessageType type, NodeId node) noexcept {
  return message_def(type).can_id(node);
}

[[nodiscard]] constexpr NodeId node_of(std::uint32_t can_id) noexcept {
  return static_cast<NodeId>(can_id & kNodeIdMask);
}

// The message a standard CAN ID belongs to (any node), or nullptr.
[[nodiscard]] constexpr const MessageDef* find_message(std::uint32_t can_id) noexcept {
  if (can_id > 0x7FFU) {
    return nullptr;
  }
  const std::uint32_t base = can_id & kIdBaseMask;
  for (const MessageDef& def : kMessages) {
    if (def.id_base == base) {
      return &def;
    }
  }
  return nullptr;
}

// The value table label of a raw value, or empty.
[[nodiscard]] constexpr std::string_view value_label(const SignalDef& signal, std::int64_t raw) noexcept {
  for (const ValueLabel& v : signal.values) {
    if (v.value == raw) {
      return v.label;
    }
  }
  return {};
}

}  // namespace pmsm::hal::protocol
