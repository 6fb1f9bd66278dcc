// The codec: CRC-8, round trips of every message, every reject reason, the alive-counter
// state machine, receivers, filters, and robustness against random frames.
#include <gtest/gtest.h>

#include <array>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <set>
#include <string_view>
#include <variant>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/crc8.hpp"
#include "pmsm/hal/protocol.hpp"
#include "pmsm/hal/protocol_filters.hpp"

namespace pmsm::hal::protocol {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using std::chrono::nanoseconds;

std::span<const std::uint8_t> bytes_of(std::string_view text) {
  return {reinterpret_cast<const std::uint8_t*>(text.data()), text.size()};  // NOLINT: byte view of ASCII
}

// ---------------------------------------------------------------------------------------
// CRC-8 SAE J1850
// ---------------------------------------------------------------------------------------

TEST(protocol_crc, CheckValueFor123456789) {
  EXPECT_EQ(crc8_sae_j1850(bytes_of("123456789")), 0x4B);
  static_assert(crc8_sae_j1850(std::array<std::uint8_t, 9>{'1', '2', '3', '4', '5', '6', '7', '8', '9'}) == 0x4B);
}

// The test vectors of the AUTOSAR "Specification of CRC Routines" for CRC8 (SAE J1850).
TEST(protocol_crc, AutosarVectors) {
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 4>{0x00, 0x00, 0x00, 0x00}), 0x59);
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 3>{0xF2, 0x01, 0x83}), 0x37);
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 4>{0x0F, 0xAA, 0x00, 0x55}), 0x79);
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 4>{0x00, 0xFF, 0x55, 0x11}), 0xB8);
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 9>{0x33, 0x22, 0x55, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF}), 0xCB);
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 3>{0x92, 0x6B, 0x55}), 0x8C);
  EXPECT_EQ(crc8_sae_j1850(std::array<std::uint8_t, 4>{0xFF, 0xFF, 0xFF, 0xFF}), 0x74);
}

TEST(protocol_crc, IncrementalEqualsOneShot) {
  Crc8SaeJ1850 crc;
  crc.update(bytes_of("1234"));
  crc.update(static_cast<std::uint8_t>('5'));
  crc.update(bytes_of("6789"));
  EXPECT_EQ(crc.value(), 0x4B);
  EXPECT_EQ(crc8_sae_j1850({}), 0x00);  // init 0xFF xor 0xFF
}

// The E2E CRC: data ID (CAN ID low byte, high byte), then payload bytes 1..7.
TEST(protocol_crc, E2eCrcCoversIdThenPayloadBytes1To7) {
  const std::array<std::uint8_t, 8> payload{0xEE, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77};
  const std::array<std::uint8_t, 9> covered{0x43, 0x00, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77};
  EXPECT_EQ(e2e_crc(0x043, payload), crc8_sae_j1850(covered));
  // Byte 0 is not covered; the ID is.
  std::array<std::uint8_t, 8> other = payload;
  other[0] = 0x00;
  EXPECT_EQ(e2e_crc(0x043, other), e2e_crc(0x043, payload));
  EXPECT_NE(e2e_crc(0x044, payload), e2e_crc(0x043, payload));
}

// The worked example of docs/protocol.md ("E2E protection"), byte for byte.
TEST(protocol_crc, DocumentedDriveCommandExample) {
  DriveCommand command;
  command.enable = true;
  command.mode = DriveMode::kTorque;
  command.torque_setpoint_Nm = 10.0;
  CanFrame f;
  ASSERT_EQ(encode(command, 3, 5, f), EncodeStatus::kOk);
  EXPECT_EQ(f.id, 0x043U);
  EXPECT_FALSE(f.fd);
  ASSERT_EQ(f.length, 8);
  const std::array<std::uint8_t, 8> expected{0x00, 0x35, 0x00, 0x00, 0x00, 0x10, 0x27, 0x00};
  for (std::size_t i = 1; i < 8; ++i) {
    EXPECT_EQ(f.data[i], expected[i]) << "byte " << i;
  }
  const std::array<std::uint8_t, 9> covered{0x43, 0x00, 0x35, 0x00, 0x00, 0x00, 0x10, 0x27, 0x00};
  EXPECT_EQ(f.data[0], crc8_sae_j1850(covered));
  EXPECT_EQ(f.data[0], 0xDD);
}

// ---------------------------------------------------------------------------------------
// Tables
// ---------------------------------------------------------------------------------------

TEST(protocol_table, IdsAreBasesWithNodeOffset) {
  std::set<std::uint32_t> ids;
  for (const MessageDef& m : kMessages) {
    EXPECT_EQ(m.id_base % 0x10, 0U) << m.name;
    for (NodeId node = 0; node <= kMaxNodeId; ++node) {
      EXPECT_TRUE(ids.insert(m.can_id(node)).second) << m.name << " node " << int{node};
      EXPECT_EQ(find_message(m.can_id(node)), &m);
      EXPECT_EQ(node_of(m.can_id(node)), node);
    }
  }
  EXPECT_EQ(ids.size(), kMessageCount * 16);
}

TEST(protocol_table, PriorityOrder) {
  // Fast loop before commands before faults before telemetry before bench frames.
  EXPECT_LT(message_def(MessageType::kInverterCommand).id_base, message_def(MessageType::kDriveCommand).id_base);
  EXPECT_LT(message_def(MessageType::kSensorSample).id_base, message_def(MessageType::kDriveCommand).id_base);
  EXPECT_LT(message_def(MessageType::kCalibrationCommand).id_base, message_def(MessageType::kFault).id_base);
  EXPECT_LT(message_def(MessageType::kFault).id_base, message_def(MessageType::kDriveStatus).id_base);
  EXPECT_LT(message_def(MessageType::kHeartbeat).id_base, message_def(MessageType::kTruthThermal).id_base);
}

TEST(protocol_table, FormatsAndLengths) {
  for (const MessageDef& m : kMessages) {
    const bool fast = m.type == MessageType::kInverterCommand || m.type == MessageType::kSensorSample;
    EXPECT_EQ(m.fd, fast) << m.name;
    if (!fast) {
      EXPECT_EQ(m.length, 8) << m.name << ": everything a user watches is a classic 8-byte frame";
    }
    const bool command = m.sender == Role::kSupervisor;
    EXPECT_EQ(m.e2e, command) << m.name;
    EXPECT_EQ(m.received_by(Role::kDaemon), fast ? m.type == MessageType::kSensorSample : command) << m.name;
  }
}

// The value tables and the C++ enums say the same (enum value == raw value, no gaps).
TEST(protocol_table, ValueTablesMatchEnums) {
  const auto check = [](std::span<const ValueLabel> labels, std::size_t count) {
    ASSERT_EQ(labels.size(), count);
    for (std::size_t i = 0; i < labels.size(); ++i) {
      EXPECT_EQ(labels[i].value, static_cast<std::int64_t>(i));
    }
  };
  check(kDriveModeLabels, 3);
  check(kInjectionMethodLabels, static_cast<std::size_t>(InjectionMethod::kDc) + 1);
  check(kCalibrationActionLabels, static_cast<std::size_t>(CalibrationAction::kAbort) + 1);
  check(kDriveStateLabels, static_cast<std::size_t>(DriveState::kFault) + 1);
  check(kInjectionResultLabels, static_cast<std::size_t>(InjectionResult::kSkippedTorqueDisturbance) + 1);
  check(kFaultCodeLabels, static_cast<std::size_t>(FaultCode::kDuplicateNode) + 1);
  check(kPlantModeLabels, 2);
  check(kCalibrationResultLabels, static_cast<std::size_t>(CalibrationResult::kRefused) + 1);
  EXPECT_EQ(thermal_estimate::kCalibrationResult.raw_max(), static_cast<std::int64_t>(CalibrationResult::kRefused));
  EXPECT_EQ(drive_command::kMode.raw_max(), 2);
  EXPECT_EQ(fault::kCode.raw_max(), static_cast<std::int64_t>(FaultCode::kDuplicateNode));
  EXPECT_EQ(injection_report::kResult.raw_max(), static_cast<std::int64_t>(InjectionResult::kSkippedTorqueDisturbance));
}

TEST(protocol_table, ResistanceResolutionIsTenMicroOhm) {
  EXPECT_DOUBLE_EQ(resistance_estimate::kRs.factor, 10e-6);
  EXPECT_DOUBLE_EQ(resistance_estimate::kRs0.factor, 10e-6);
  EXPECT_DOUBLE_EQ(injection_report::kMeasuredRs.factor, 10e-6);
}

// ---------------------------------------------------------------------------------------
// Round trips
// ---------------------------------------------------------------------------------------

template <class T>
T round_trip(const T& in, NodeId node = 5) {
  CanFrame f;
  const EncodeStatus es = encode(in, node, f);
  EXPECT_EQ(es, EncodeStatus::kOk);
  T out{};
  EXPECT_EQ(decode(f, node, out), DecodeStatus::kOk);
  return out;
}

template <class T>
T command_round_trip(const T& in, std::uint8_t counter = 7, NodeId node = 5) {
  CanFrame f;
  EXPECT_EQ(encode(in, node, counter, f), EncodeStatus::kOk);
  T out{};
  std::uint8_t got = 0xFF;
  EXPECT_EQ(decode(f, node, out, got), DecodeStatus::kOk);
  EXPECT_EQ(got, counter);
  return out;
}

TEST(protocol_codec, SensorSampleRoundTripExtremes) {
  for (const std::int16_t v : {std::numeric_limits<std::int16_t>::min(), std::int16_t{-1}, std::int16_t{0},
                               std::numeric_limits<std::int16_t>::max()}) {
    SensorSample s;
    s.sequence = 0xFFFF'FFFFU;
    s.phase_current_adc = {v, static_cast<std::int16_t>(-v / 2), std::int16_t{123}};
    s.encoder_count = 0xFFFF;
    s.dc_bus_adc = 0;
    s.phase_voltage_adc = {std::int16_t{-32768}, v, std::int16_t{32767}};
    s.flags = kSensorOutputEnabled | kSensorPhaseVoltageValid | kSensorHardwareOvercurrent;
    const SensorSample r = round_trip(s);
    EXPECT_EQ(r.sequence, s.sequence);
    EXPECT_EQ(r.phase_current_adc, s.phase_current_adc);
    EXPECT_EQ(r.encoder_count, s.encoder_count);
    EXPECT_EQ(r.dc_bus_adc, s.dc_bus_adc);
    EXPECT_EQ(r.phase_voltage_adc, s.phase_voltage_adc);
    EXPECT_EQ(r.flags, s.flags);
  }
  SensorSample zero;
  const SensorSample r = round_trip(zero);
  EXPECT_EQ(r.flags, 0);
  EXPECT_EQ(r.sequence, 0U);
}

TEST(protocol_codec, SensorSampleFrameShape) {
  SensorSample s;
  s.sequence = 0x04030201;
  s.phase_current_adc = {std::int16_t{-2}, std::int16_t{0x0102}, std::int16_t{0}};
  s.flags = kSensorPhaseVoltageValid;
  CanFrame f;
  ASSERT_EQ(encode(s, 2, f), EncodeStatus::kOk);
  EXPECT_EQ(f.id, 0x022U);
  EXPECT_TRUE(f.fd);
  EXPECT_FALSE(f.extended);
  EXPECT_EQ(f.length, 24);
  EXPECT_EQ(f.data[0], 0x01);  // little-endian sequence
  EXPECT_EQ(f.data[3], 0x04);
  EXPECT_EQ(f.data[4], 0xFE);  // -2
  EXPECT_EQ(f.data[5], 0xFF);
  EXPECT_EQ(f.data[6], 0x02);
  EXPECT_EQ(f.data[7], 0x01);
  EXPECT_EQ(f.data[20], 0x02);  // flags (bits 160-163), PwmPeriod's low nibble 0
  for (std::size_t i = 21; i < 24; ++i) {
    EXPECT_EQ(f.data[i], 0) << "byte " << i << ": PwmPeriod not reported, no ambient";
  }
  // PwmPeriod: 12 bits from bit 164, little-endian; the frame has no reserved bits left.
  s.pwm_period_code = 0xABC;
  ASSERT_EQ(encode(s, 2, f), EncodeStatus::kOk);
  EXPECT_EQ(f.data[20], 0xC2);
  EXPECT_EQ(f.data[21], 0xAB);
}

// The power stage's period: every code the field holds comes back; one it cannot hold goes out
// as 0 ("not reported", not wrapped into another period) and the encoder says so.
TEST(protocol_codec, SensorSamplePwmPeriod) {
  for (const std::uint16_t code : {std::uint16_t{0}, std::uint16_t{1}, std::uint16_t{400}, kPwmPeriodMaxCode}) {
    SensorSample s;
    s.pwm_period_code = code;
    EXPECT_EQ(round_trip(s).pwm_period_code, code);
  }
  SensorSample s;
  s.pwm_period_code = kPwmPeriodMaxCode + 1;
  CanFrame f;
  EXPECT_EQ(encode(s, 0, f), EncodeStatus::kInvalidValue);
  SensorSample back;
  back.pwm_period_code = 1;
  ASSERT_EQ(decode(f, 0, back), DecodeStatus::kOk);
  EXPECT_EQ(back.pwm_period_code, 0U);
  EXPECT_EQ(pwm_period_code(10000.0), 400U);   // 100 us
  EXPECT_EQ(pwm_period_code(15000.0), 267U);   // 66.67 us -> 66.75
  EXPECT_EQ(pwm_period_code(1000.0), 4000U);   // 1 ms: the slowest control period fits
  EXPECT_EQ(pwm_period_code(900.0), 0U);       // beyond the field: not reported
  EXPECT_EQ(pwm_period_code(std::numeric_limits<double>::quiet_NaN()), 0U);
}

TEST(protocol_codec, InverterCommandRoundTripExtremes) {
  for (const std::uint16_t d : {std::uint16_t{0}, std::uint16_t{1}, std::uint16_t{32768}, std::uint16_t{65535}}) {
    InverterCommand c;
    c.sequence = 123456789U;
    c.duty = {d, static_cast<std::uint16_t>(65535 - d), std::uint16_t{4242}};
    c.enable = (d % 2U) == 0U;
    const InverterCommand r = round_trip(c, 15);
    EXPECT_EQ(r.sequence, c.sequence);
    EXPECT_EQ(r.duty, c.duty);
    EXPECT_EQ(r.enable, c.enable);
  }
  CanFrame f;
  ASSERT_EQ(encode(InverterCommand{}, 0, f), EncodeStatus::kOk);
  EXPECT_EQ(f.id, 0x010U);
  EXPECT_TRUE(f.fd);
  EXPECT_EQ(f.length, 12);
}

TEST(protocol_codec, DriveCommandRoundTripExtremes) {
  for (const double speed : {-2000.0, -0.001, 0.0, 314.159, 2000.0}) {
    for (const double torque : {-1000.0, 0.0, 2.08, 1000.0}) {
      DriveCommand c;
      c.enable = speed > 0;
      c.mode = speed > 0 ? DriveMode::kSpeed : DriveMode::kTorque;
      c.speed_setpoint_rad_s = speed;
      c.torque_setpoint_Nm = torque;
      const DriveCommand r = command_round_trip(c);
      EXPECT_EQ(r.enable, c.enable);
      EXPECT_EQ(r.mode, c.mode);
      EXPECT_NEAR(r.speed_setpoint_rad_s, speed, 0.0005);
      EXPECT_NEAR(r.torque_setpoint_Nm, torque, 0.0005);
    }
  }
}

TEST(protocol_codec, InjectionAndCalibrationCommandsRoundTrip) {
  for (int m = 0; m <= static_cast<int>(InjectionMethod::kDc); ++m) {
    InjectionCommand c;
    c.method = static_cast<InjectionMethod>(m);
    c.amplitude_A = m * 50.0 + 0.01;
    c.interval_s = m == 0 ? 0.0 : 6000.0 / m;
    c.request_now = m % 2 == 1;
    const InjectionCommand r = command_round_trip(c, static_cast<std::uint8_t>(m));
    EXPECT_EQ(r.method, c.method);
    EXPECT_NEAR(r.amplitude_A, c.amplitude_A, 0.005);
    EXPECT_NEAR(r.interval_s, c.interval_s, 0.05);
    EXPECT_EQ(r.request_now, c.request_now);
  }
  for (const double t : {-40.0, 25.0, 150.0}) {
    for (const CalibrationAction a : {CalibrationAction::kNone, CalibrationAction::kStart, CalibrationAction::kAbort}) {
      CalibrationCommand c;
      c.action = a;
      c.known_temp_C = t;
      const CalibrationCommand r = command_round_trip(c, 15);
      EXPECT_EQ(r.action, a);
      EXPECT_NEAR(r.known_temp_C, t, 0.005);
    }
  }
}

TEST(protocol_codec, TelemetryRoundTrip) {
  FaultReport fault;
  fault.code = FaultCode::kInternal;
  fault.active = true;
  fault.occurrence_count = 65535;
  fault.last_change_uptime_s = 42949672.95;
  const FaultReport fr = round_trip(fault);
  EXPECT_EQ(fr.code, fault.code);
  EXPECT_TRUE(fr.active);
  EXPECT_EQ(fr.occurrence_count, 65535U);
  EXPECT_NEAR(fr.last_change_uptime_s, 42949672.95, 0.005);

  DriveStatus status;
  status.state = DriveState::kFault;
  status.limiting_reasons = kLimitReasonWindingTemp | kLimitReasonSpeed;
  status.current_limit_A = 400.0;
  status.time_to_limit_valid = true;
  status.time_to_limit_s = 8191.0;
  status.motion_valid = true;
  status.speed_rad_s = -3200.0;
  status.torque_Nm = 400.0;
  const DriveStatus sr = round_trip(status);
  EXPECT_EQ(sr.state, status.state);
  EXPECT_EQ(sr.limiting_reasons, status.limiting_reasons);
  EXPECT_NEAR(sr.current_limit_A, 400.0, 0.05);
  EXPECT_TRUE(sr.time_to_limit_valid);
  EXPECT_NEAR(sr.time_to_limit_s, 8191.0, 0.5);
  EXPECT_TRUE(sr.motion_valid);
  EXPECT_NEAR(sr.speed_rad_s, -3200.0, 0.1);
  // A field-weakening spindle's 1885 rad/s, which the 1.2 layout's +-1600 clamped.
  status.speed_rad_s = 1885.0;
  EXPECT_NEAR(round_trip(status).speed_rad_s, 1885.0, 0.1);
  EXPECT_NEAR(sr.torque_Nm, 400.0, 0.025);
  // A drive that tracks no shaft (no usable sample) says so: no speed and no torque, whatever
  // the struct held, rather than the last reading of a shaft that may have stopped.
  status.motion_valid = false;
  CanFrame still;
  ASSERT_EQ(encode(status, 3, still), EncodeStatus::kOk);
  const DriveStatus none = round_trip(status);
  EXPECT_FALSE(none.motion_valid);
  EXPECT_TRUE(std::isnan(none.speed_rad_s));
  EXPECT_TRUE(std::isnan(none.torque_Nm));
  std::uint64_t word = 0;
  for (std::size_t k = 0; k < 8; ++k) {
    word |= std::uint64_t{still.data[k]} << (8U * k);
  }
  static_assert(drive_status::kSpeed.start_bit == 35 && drive_status::kTorque.start_bit + drive_status::kTorque.length == 64);
  EXPECT_EQ(word >> 35U, 0U) << "Speed and Torque go out as raw 0 without a reading";

  ThermalEstimate thermal;
  thermal.valid = true;
  thermal.winding_temp_C = 120.37;
  thermal.winding_temp_sigma_C = 2.5;
  thermal.magnet_valid = true;
  thermal.magnet_temp_C = -50.0;
  thermal.magnet_temp_sigma_C = 3.3;
  thermal.calibrated = true;
  thermal.derating_active = true;
  thermal.stale = true;
  thermal.calibrating = true;
  const ThermalEstimate tr = round_trip(thermal);
  EXPECT_NEAR(tr.winding_temp_C, 120.37, 0.005);
  EXPECT_NEAR(tr.winding_temp_sigma_C, 2.5, 0.005);
  EXPECT_NEAR(tr.magnet_temp_C, -50.0, 0.005);
  EXPECT_NEAR(tr.magnet_temp_sigma_C, 3.25, 1e-12) << "the 0.25 C grid";
  thermal.magnet_temp_sigma_C = 80.0;
  CanFrame saturated;
  EXPECT_EQ(encode(thermal, 0, saturated), EncodeStatus::kSaturated);
  ThermalEstimate wide;
  ASSERT_EQ(decode(saturated, 0, wide), DecodeStatus::kOk);
  EXPECT_EQ(wide.magnet_temp_sigma_C, 31.75) << "a wider bar reads as the largest, never as a narrow one";
  thermal.magnet_temp_sigma_C = 3.3;
  EXPECT_TRUE(tr.valid && tr.magnet_valid && tr.calibrated && tr.derating_active && tr.stale && tr.calibrating);
  thermal.calibrating = false;
  EXPECT_FALSE(round_trip(thermal).calibrating);
  for (const CalibrationResult result : {CalibrationResult::kNone, CalibrationResult::kDone, CalibrationResult::kAborted,
                                         CalibrationResult::kTimedOut, CalibrationResult::kRefused}) {
    thermal.calibration_result = result;
    EXPECT_EQ(round_trip(thermal).calibration_result, result);
  }
  {
    // Raw 5-7 in its three bits (53-55) is no result this protocol knows: the frame is refused.
    CanFrame f;
    ASSERT_EQ(encode(thermal, 5, f), EncodeStatus::kOk);
    f.data[6] = static_cast<std::uint8_t>((f.data[6] & ~0xE0U) | (5U << 5));
    ThermalEstimate out{};
    EXPECT_EQ(decode(f, 5, out), DecodeStatus::kOutOfRange);
  }

  ResistanceEstimate rs;
  rs.valid = true;
  rs.rs_ohm = 0.13301;
  rs.rs_sigma_ohm = 0.00123;
  rs.rs0_ohm = 0.133;
  rs.estimate_count = 1023;
  const ResistanceEstimate rr = round_trip(rs);
  EXPECT_NEAR(rr.rs_ohm, 0.13301, 5e-6);
  EXPECT_NEAR(rr.rs_sigma_ohm, 0.00123, 5e-6);
  EXPECT_NEAR(rr.rs0_ohm, 0.133, 5e-6);
  EXPECT_EQ(rr.estimate_count, 1023);

  InjectionReport report;
  report.injection_count = 255;
  report.method = InjectionMethod::kFixedAngleUnipolar;
  report.result = InjectionResult::kRejectedVoltageHeadroom;
  report.amplitude_A = 75.0;
  report.rs_valid = true;
  report.measured_rs_ohm = 0.18321;
  report.speed_change_valid = true;
  report.speed_change_rad_s = -32.768;
  const InjectionReport ir = round_trip(report);
  EXPECT_EQ(ir.injection_count, 255);
  EXPECT_EQ(ir.method, report.method);
  EXPECT_EQ(ir.result, report.result);
  EXPECT_NEAR(ir.amplitude_A, 75.0, 0.05);
  EXPECT_TRUE(ir.rs_valid);
  EXPECT_NEAR(ir.measured_rs_ohm, 0.18321, 5e-6);
  EXPECT_TRUE(ir.speed_change_valid);
  EXPECT_NEAR(ir.speed_change_rad_s, -32.768, 1e-3);
  report.speed_change_valid = false;  // an aborted pair: no speed change, not a change of 0
  EXPECT_TRUE(std::isnan(round_trip(report).speed_change_rad_s));

  Heartbeat hb;
  hb.uptime_s = 3600.25;
  hb.state = DriveState::kRunning;
  hb.counter = 200;
  hb.deadline_misses = 3;
  hb.ambient_source = AmbientSource::kHeld;
  const Heartbeat hr = round_trip(hb);
  EXPECT_NEAR(hr.uptime_s, 3600.25, 0.005);
  EXPECT_EQ(hr.state, DriveState::kRunning);
  EXPECT_EQ(hr.counter, 200);
  EXPECT_EQ(hr.deadline_misses, 3U);
  EXPECT_EQ(hr.ambient_source, AmbientSource::kHeld);

  ReceiveStatus rcv;
  rcv.last_rejection = static_cast<std::uint8_t>(DecodeStatus::kBadCrc);
  rcv.last_rejected_id = 0x047;
  rcv.commands_accepted = 300;  // sent modulo 256
  rcv.rejected_crc = 3;
  rcv.rejected_counter = 258;
  rcv.rejected_range = 1;
  rcv.rejected_format = 4;
  rcv.rejected_other = 0;
  const ReceiveStatus rcv_back = round_trip(rcv);
  EXPECT_EQ(rcv_back.last_rejection, static_cast<std::uint8_t>(DecodeStatus::kBadCrc));
  EXPECT_EQ(rcv_back.last_rejected_id, 0x047);
  EXPECT_EQ(rcv_back.commands_accepted, 300U % 256U);
  EXPECT_EQ(rcv_back.rejected_crc, 3U);
  EXPECT_EQ(rcv_back.rejected_counter, 2U);
  EXPECT_EQ(rcv_back.rejected_range, 1U);
  EXPECT_EQ(rcv_back.rejected_format, 4U);

  LoopTiming timing;
  timing.latency_p50_us = 16;
  timing.latency_p99_us = 8192;  // beyond the signal: saturates
  timing.latency_max_us = 87.34;
  timing.periods = 10000;
  timing.deadline_misses = 2;
  CanFrame f{};
  EXPECT_EQ(encode(timing, 2, f), EncodeStatus::kSaturated);
  LoopTiming timing_back;
  ASSERT_EQ(decode(f, 2, timing_back), DecodeStatus::kOk);
  EXPECT_EQ(timing_back.latency_p50_us, 16.0);
  EXPECT_EQ(timing_back.latency_p99_us, 4095.0);
  EXPECT_NEAR(timing_back.latency_max_us, 87.3, 0.051);
  EXPECT_EQ(timing_back.periods, 10000U);
  EXPECT_EQ(timing_back.deadline_misses, 2U);
}

// RECEIVE_STATUS's value table names the codec's DecodeStatus values.
TEST(protocol_codec, ReceiveStatusLabelsAreTheDecodeStatuses) {
  ASSERT_EQ(kDecodeStatusLabels.size(), kDecodeStatusCount);
  for (std::size_t i = 1; i < kDecodeStatusCount; ++i) {
    std::string label(kDecodeStatusLabels[i].label);
    for (char& c : label) {
      c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    }
    EXPECT_EQ(kDecodeStatusLabels[i].value, static_cast<std::int64_t>(i));
    EXPECT_EQ(label, to_string(static_cast<DecodeStatus>(i)));
  }
}

TEST(protocol_codec, BenchFramesRoundTrip) {
  TruthSample truth;
  truth.winding_temp_C = 155.5F;
  truth.housing_temp_C = 80.25F;
  truth.magnet_temp_C = 99.0F;
  truth.rs_ohm = 0.18F;
  truth.torque_Nm = -123.45F;
  truth.speed_rad_s = 314.0F;
  truth.load_torque_Nm = 100.0F;
  const TruthThermal tt = round_trip(truth_thermal_from(truth, 40.0));
  EXPECT_NEAR(tt.winding_temp_C, 155.5, 0.005);
  EXPECT_NEAR(tt.housing_temp_C, 80.25, 0.005);
  EXPECT_NEAR(tt.magnet_temp_C, 99.0, 0.005);
  EXPECT_NEAR(tt.ambient_temp_C, 40.0, 0.005);
  const TruthElectrical te = round_trip(truth_electrical_from(truth));
  EXPECT_NEAR(te.rs_ohm, 0.18, 1e-5);
  EXPECT_NEAR(te.torque_Nm, -123.45, 0.025);
  EXPECT_NEAR(te.speed_rad_s, 314.0, 0.05);
  EXPECT_NEAR(te.load_torque_Nm, 100.0, 0.025);

  PlantStatus ps;
  ps.mode = PlantMode::kLockstep;
  ps.output_enabled = true;
  ps.command_timeout_tripped = true;
  ps.late_commands = 12;
  ps.missing_commands = 65535;
  ps.simulated_time_s = 167772.15;
  const PlantStatus pr = round_trip(ps);
  EXPECT_EQ(pr.mode, PlantMode::kLockstep);
  EXPECT_TRUE(pr.output_enabled && pr.command_timeout_tripped);
  EXPECT_EQ(pr.late_commands, 12U);
  EXPECT_EQ(pr.missing_commands, 65535U);
  EXPECT_NEAR(pr.simulated_time_s, 167772.15, 0.005);
}

// ---------------------------------------------------------------------------------------
// Encoder policy: validity bits, NaN, saturation, wrapping, bad enums, bad node
// ---------------------------------------------------------------------------------------

TEST(protocol_codec, ClearedValidityBitMeansZeroOnTheWireAndNaNDecoded) {
  ThermalEstimate t;
  t.valid = false;
  t.winding_temp_C = std::numeric_limits<double>::quiet_NaN();
  t.winding_temp_sigma_C = std::numeric_limits<double>::infinity();
  t.magnet_valid = false;
  t.magnet_temp_C = 999.0;
  t.magnet_temp_sigma_C = 5.0;
  CanFrame f;
  ASSERT_EQ(encode(t, 0, f), EncodeStatus::kOk);
  for (std::size_t i = 0; i < 6; ++i) {
    EXPECT_EQ(f.data[i], 0) << i;
  }
  ThermalEstimate r;
  ASSERT_EQ(decode(f, 0, r), DecodeStatus::kOk);
  EXPECT_TRUE(std::isnan(r.winding_temp_C));
  EXPECT_TRUE(std::isnan(r.winding_temp_sigma_C));
  EXPECT_TRUE(std::isnan(r.magnet_temp_C));
  EXPECT_TRUE(std::isnan(r.magnet_temp_sigma_C));
  EXPECT_EQ(f.data[7] >> 1, 0) << "MagnetTempSigma is 0 on the wire without MagnetValid";

  DriveStatus s;
  s.time_to_limit_valid = false;
  s.time_to_limit_s = 1e9;
  ASSERT_EQ(encode(s, 0, f), EncodeStatus::kOk);
  DriveStatus sr;
  ASSERT_EQ(decode(f, 0, sr), DecodeStatus::kOk);
  EXPECT_FALSE(sr.time_to_limit_valid);
  EXPECT_TRUE(std::isnan(sr.time_to_limit_s));
}

TEST(protocol_codec, NotFiniteValueIsInvalid) {
  ThermalEstimate t;
  t.valid = true;
  t.winding_temp_C = std::numeric_limits<double>::quiet_NaN();
  CanFrame f;
  EXPECT_EQ(encode(t, 0, f), EncodeStatus::kInvalidValue);
  DriveCommand c;
  c.speed_setpoint_rad_s = -std::numeric_limits<double>::infinity();
  EXPECT_EQ(encode(c, 0, 0, f), EncodeStatus::kInvalidValue);
}

TEST(protocol_codec, OutOfRangeValuesSaturate) {
  ThermalEstimate t;
  t.valid = true;
  t.winding_temp_C = 400.0;
  t.winding_temp_sigma_C = -1.0;
  CanFrame f;
  EXPECT_EQ(encode(t, 0, f), EncodeStatus::kSaturated);
  ThermalEstimate r;
  ASSERT_EQ(decode(f, 0, r), DecodeStatus::kOk);  // saturated values are in range
  EXPECT_DOUBLE_EQ(r.winding_temp_C, 300.0);
  EXPECT_DOUBLE_EQ(r.winding_temp_sigma_C, 0.0);

  Heartbeat hb;
  hb.deadline_misses = 1'000'000;
  hb.counter = 255;
  EXPECT_EQ(encode(hb, 0, f), EncodeStatus::kSaturated);
  Heartbeat hr;
  ASSERT_EQ(decode(f, 0, hr), DecodeStatus::kOk);
  EXPECT_EQ(hr.deadline_misses, 65535U);

  // Rounding to the grid right at the limit is not saturation.
  t.winding_temp_C = 300.004;
  t.winding_temp_sigma_C = 0.0;
  EXPECT_EQ(encode(t, 0, f), EncodeStatus::kOk);
}

TEST(protocol_codec, WrappingCountersWrap) {
  ResistanceEstimate rs;
  rs.estimate_count = 1024 + 7;
  CanFrame f;
  EXPECT_EQ(encode(rs, 0, f), EncodeStatus::kOk);
  ResistanceEstimate r;
  ASSERT_EQ(decode(f, 0, r), DecodeStatus::kOk);
  EXPECT_EQ(r.estimate_count, 7);
}

TEST(protocol_codec, EnumOutsideItsTableIsInvalid) {
  DriveCommand c;
  c.mode = static_cast<DriveMode>(3);
  CanFrame f;
  EXPECT_EQ(encode(c, 0, 0, f), EncodeStatus::kInvalidValue);
  FaultReport fr;
  fr.code = static_cast<FaultCode>(200);
  EXPECT_EQ(encode(fr, 0, f), EncodeStatus::kInvalidValue);
}

TEST(protocol_codec, InvalidNodeWritesNothing) {
  CanFrame f;
  f.id = 0x555;
  EXPECT_EQ(encode(SensorSample{}, 16, f), EncodeStatus::kInvalidNode);
  EXPECT_EQ(f.id, 0x555U);
  EXPECT_EQ(encode(DriveCommand{}, 200, 0, f), EncodeStatus::kInvalidNode);
  EXPECT_EQ(f.id, 0x555U);
}

// ---------------------------------------------------------------------------------------
// Rejections, each reason triggered and counted
// ---------------------------------------------------------------------------------------

CanFrame drive_frame(NodeId node, std::uint8_t counter, const DriveCommand& c = {}) {
  CanFrame f;
  EXPECT_EQ(encode(c, node, counter, f), EncodeStatus::kOk);
  return f;
}

void restamp_crc(CanFrame& f) { f.data[0] = e2e_crc(f.id, std::span<const std::uint8_t, 8>(f.data.data(), 8)); }

TEST(protocol_reject, StatelessDecodeReasons) {
  SensorSample s;
  CanFrame f;
  ASSERT_EQ(encode(SensorSample{}, 4, f), EncodeStatus::kOk);

  CanFrame g = f;
  g.id = 0x7FF;
  EXPECT_EQ(decode(g, 4, s), DecodeStatus::kUnknownId);
  g = f;
  g.extended = true;
  EXPECT_EQ(decode(g, 4, s), DecodeStatus::kUnknownId);
  g = f;
  g.error = true;
  EXPECT_EQ(decode(g, 4, s), DecodeStatus::kUnknownId);
  EXPECT_EQ(decode(f, 5, s), DecodeStatus::kWrongNode);
  g = f;
  g.fd = false;
  EXPECT_EQ(decode(g, 4, s), DecodeStatus::kWrongFrameFormat);
  g = f;
  g.length = 20;
  EXPECT_EQ(decode(g, 4, s), DecodeStatus::kWrongLength);

  DriveCommand c;
  std::uint8_t counter = 0;
  CanFrame d = drive_frame(4, 1);
  d.data[3] ^= 0x01U;
  EXPECT_EQ(decode(d, 4, c, counter), DecodeStatus::kBadCrc);
  d = drive_frame(4, 1);
  d.data[0] ^= 0x80U;
  EXPECT_EQ(decode(d, 4, c, counter), DecodeStatus::kBadCrc);
  // A frame replayed under another node's ID fails the CRC (the ID is the data ID).
  d = drive_frame(4, 1);
  d.id = message_def(MessageType::kDriveCommand).can_id(5);
  EXPECT_EQ(decode(d, 5, c, counter), DecodeStatus::kBadCrc);
  // Mode 3 with a valid CRC.
  d = drive_frame(4, 1);
  d.data[1] |= 0x60U;
  restamp_crc(d);
  EXPECT_EQ(decode(d, 4, c, counter), DecodeStatus::kOutOfRange);
  d = drive_frame(4, 1);
  d.length = 7;
  EXPECT_EQ(decode(d, 4, c, counter), DecodeStatus::kWrongLength);
}

TEST(protocol_reject, DaemonReceiverCountsEveryReason) {
  DaemonReceiver rx(4);
  nanoseconds now{0};
  const auto feed = [&](const CanFrame& f) {
    now += milliseconds(1);
    return rx.receive(f, now);
  };
  const auto reason = [](const DaemonInput& in) {
    const auto* r = std::get_if<Rejected>(&in);
    return r != nullptr ? r->reason : DecodeStatus::kOk;
  };

  // kOk: first command frame of a stream, whatever its counter.
  EXPECT_EQ(reason(feed(drive_frame(4, 9))), DecodeStatus::kOk);
  EXPECT_EQ(reason(feed(drive_frame(4, 10))), DecodeStatus::kOk);
  // kRepeatedCounter
  EXPECT_EQ(reason(feed(drive_frame(4, 10))), DecodeStatus::kRepeatedCounter);
  // kOk with one frame lost (delta 2 = default max delta), across the wrap 15 -> 0.
  EXPECT_EQ(reason(feed(drive_frame(4, 12))), DecodeStatus::kOk);
  EXPECT_EQ(reason(feed(drive_frame(4, 14))), DecodeStatus::kOk);
  EXPECT_EQ(reason(feed(drive_frame(4, 0))), DecodeStatus::kOk);
  // kCounterJump: delta 5; then re-synchronised on it.
  EXPECT_EQ(reason(feed(drive_frame(4, 5))), DecodeStatus::kCounterJump);
  EXPECT_EQ(reason(feed(drive_frame(4, 6))), DecodeStatus::kOk);
  // An old frame (delta 15 = -1) is a jump, not acceptance.
  EXPECT_EQ(reason(feed(drive_frame(4, 5))), DecodeStatus::kCounterJump);
  EXPECT_EQ(reason(feed(drive_frame(4, 6))), DecodeStatus::kOk);
  // kBadCrc does not advance the counter.
  CanFrame bad = drive_frame(4, 7);
  bad.data[4] ^= 0x10U;
  EXPECT_EQ(reason(feed(bad)), DecodeStatus::kBadCrc);
  EXPECT_EQ(reason(feed(drive_frame(4, 7))), DecodeStatus::kOk);
  // kOutOfRange: a genuine frame (counter advances, as in AUTOSAR) with mode 3.
  CanFrame mode3 = drive_frame(4, 8);
  mode3.data[1] |= 0x60U;
  restamp_crc(mode3);
  EXPECT_EQ(reason(feed(mode3)), DecodeStatus::kOutOfRange);
  EXPECT_EQ(reason(feed(drive_frame(4, 9))), DecodeStatus::kOk);
  // kOutOfRange on a setpoint beyond its maximum (raw 2000.001 rad/s).
  CanFrame fast = drive_frame(4, 10);
  fast.data[2] = 0xD1;  // 2000001 = 0x1E8481
  fast.data[3] = 0x84;
  fast.data[4] = 0x1E;
  restamp_crc(fast);
  EXPECT_EQ(reason(feed(fast)), DecodeStatus::kOutOfRange);
  // kWrongNode, kWrongLength, kWrongFrameFormat, kUnknownId.
  EXPECT_EQ(reason(feed(drive_frame(3, 11))), DecodeStatus::kWrongNode);
  CanFrame short_frame = drive_frame(4, 11);
  short_frame.length = 6;
  EXPECT_EQ(reason(feed(short_frame)), DecodeStatus::kWrongLength);
  CanFrame fd_command = drive_frame(4, 11);
  fd_command.fd = true;
  EXPECT_EQ(reason(feed(fd_command)), DecodeStatus::kWrongFrameFormat);
  CanFrame classic_sample;
  ASSERT_EQ(encode(SensorSample{}, 4, classic_sample), EncodeStatus::kOk);
  classic_sample.fd = false;
  classic_sample.length = 8;
  EXPECT_EQ(reason(feed(classic_sample)), DecodeStatus::kWrongFrameFormat);
  CanFrame telemetry;
  ASSERT_EQ(encode(Heartbeat{}, 4, telemetry), EncodeStatus::kOk);
  EXPECT_EQ(reason(feed(telemetry)), DecodeStatus::kUnknownId);  // not for the daemon
  CanFrame stranger;
  stranger.id = 0x7EF;
  stranger.length = 8;
  EXPECT_EQ(reason(feed(stranger)), DecodeStatus::kUnknownId);

  const DecodeCounters& c = rx.counters();
  EXPECT_EQ(c[DecodeStatus::kOk], 9U);
  EXPECT_EQ(c[DecodeStatus::kRepeatedCounter], 1U);
  EXPECT_EQ(c[DecodeStatus::kCounterJump], 2U);
  EXPECT_EQ(c[DecodeStatus::kBadCrc], 1U);
  EXPECT_EQ(c[DecodeStatus::kOutOfRange], 2U);
  EXPECT_EQ(c[DecodeStatus::kWrongNode], 1U);
  EXPECT_EQ(c[DecodeStatus::kWrongLength], 1U);
  EXPECT_EQ(c[DecodeStatus::kWrongFrameFormat], 2U);
  EXPECT_EQ(c[DecodeStatus::kUnknownId], 2U);
  EXPECT_EQ(c.accepted(), 9U);
  EXPECT_EQ(c.rejected(), 12U);
  EXPECT_EQ(rx.counters(MessageType::kDriveCommand).accepted(), 9U);
  EXPECT_EQ(rx.counters(MessageType::kDriveCommand).rejected(), 9U);
  EXPECT_EQ(rx.counters(MessageType::kSensorSample)[DecodeStatus::kWrongFrameFormat], 1U);
}

TEST(protocol_reject, CommandStreamsAreIndependent) {
  DaemonReceiver rx(0);
  CommandSender tx(0);
  CanFrame f;
  ASSERT_EQ(tx.encode(DriveCommand{}, f), EncodeStatus::kOk);
  EXPECT_TRUE(std::holds_alternative<DriveCommand>(rx.receive(f, nanoseconds{1})));
  ASSERT_EQ(tx.encode(InjectionCommand{}, f), EncodeStatus::kOk);
  EXPECT_TRUE(std::holds_alternative<InjectionCommand>(rx.receive(f, nanoseconds{2})));
  ASSERT_EQ(tx.encode(CalibrationCommand{}, f), EncodeStatus::kOk);
  EXPECT_TRUE(std::holds_alternative<CalibrationCommand>(rx.receive(f, nanoseconds{3})));
  for (int i = 0; i < 40; ++i) {  // many wraps of the 4-bit counter
    ASSERT_EQ(tx.encode(DriveCommand{}, f), EncodeStatus::kOk);
    EXPECT_TRUE(std::holds_alternative<DriveCommand>(rx.receive(f, nanoseconds{10 + i}))) << i;
  }
  EXPECT_EQ(tx.next_counter(CommandStream::kDrive), (41 % 16));
  EXPECT_EQ(tx.next_counter(CommandStream::kInjection), 1);
  EXPECT_EQ(rx.counters().rejected(), 0U);
}

TEST(protocol_reject, ACommandAmongCorruptFramesOfItsStreamIsNotActedOn) {
  DaemonReceiver rx(4);
  CommandSender tx(4);
  nanoseconds now{0};
  const auto reason = [](const DaemonInput& in) {
    const auto* r = std::get_if<Rejected>(&in);
    return r != nullptr ? r->reason : DecodeStatus::kOk;
  };
  DriveCommand run;
  run.enable = true;
  run.mode = DriveMode::kSpeed;
  run.speed_setpoint_rad_s = 50.0;
  DriveCommand faster = run;
  faster.speed_setpoint_rad_s = 60.0;
  const auto genuine = [&](milliseconds after, const DriveCommand& c) {
    now += after;
    CanFrame f;
    EXPECT_EQ(tx.encode(c, f), EncodeStatus::kOk);
    return reason(rx.receive(f, now));
  };
  const auto corrupt = [&](milliseconds after) {
    now += after;
    CanFrame f = drive_frame(4, 0);
    f.data[5] ^= 0x01U;
    return reason(rx.receive(f, now));
  };
  EXPECT_EQ(genuine(milliseconds(20), run), DecodeStatus::kOk);  // at 20 ms
  // One corrupt frame (a supervisor's slip) holds nothing back.
  EXPECT_EQ(corrupt(milliseconds(5)), DecodeStatus::kBadCrc);  // 25 ms
  EXPECT_EQ(genuine(milliseconds(15), faster), DecodeStatus::kOk);
  EXPECT_FALSE(rx.disturbed(CommandStream::kDrive, now));
  // A second within kDisturbedWindow: a new order that passes its checks now is held back,
  // though its alive counter is followed (the frames after it are no jump).
  EXPECT_EQ(corrupt(milliseconds(500)), DecodeStatus::kBadCrc);  // 540 ms
  EXPECT_TRUE(rx.disturbed(CommandStream::kDrive, now));
  CanFrame wrong_length;
  EXPECT_EQ(tx.encode(run, wrong_length), EncodeStatus::kOk);
  wrong_length.length = 7;
  now += milliseconds(1);
  EXPECT_EQ(reason(rx.receive(wrong_length, now)), DecodeStatus::kWrongLength);  // 541 ms: a third failure
  EXPECT_EQ(genuine(milliseconds(19), run), DecodeStatus::kStreamDisturbed);  // a new set-point
  // A repeat of the last command acted on changes nothing and keeps the supervisor heard.
  EXPECT_EQ(genuine(milliseconds(20), faster), DecodeStatus::kOk);
  // A stop is acted on through any disturbance (it can only take the drive to its safe state),
  // and so is a calibration's abort; a calibration's start is not.
  EXPECT_EQ(genuine(milliseconds(1), DriveCommand{}), DecodeStatus::kOk);  // 581 ms, disabled
  EXPECT_EQ(genuine(milliseconds(1), faster), DecodeStatus::kStreamDisturbed);  // after the stop: a start
  for (const CalibrationAction action : {CalibrationAction::kStart, CalibrationAction::kAbort}) {
    CanFrame bad_calibration;
    EXPECT_EQ(CommandSender(4).encode(CalibrationCommand{}, bad_calibration), EncodeStatus::kOk);
    bad_calibration.data[6] ^= 0x01U;
    EXPECT_EQ(reason(rx.receive(bad_calibration, now)), DecodeStatus::kBadCrc);
    EXPECT_EQ(reason(rx.receive(bad_calibration, now)), DecodeStatus::kBadCrc);
    CalibrationCommand c;
    c.action = action;
    c.known_temp_C = 25.0;
    CanFrame f;
    EXPECT_EQ(tx.encode(c, f), EncodeStatus::kOk);
    EXPECT_EQ(reason(rx.receive(f, now)),
              action == CalibrationAction::kAbort ? DecodeStatus::kOk : DecodeStatus::kStreamDisturbed);
  }
  // The other streams are their own.
  CanFrame injection;
  EXPECT_EQ(tx.encode(InjectionCommand{}, injection), EncodeStatus::kOk);
  EXPECT_TRUE(std::holds_alternative<InjectionCommand>(rx.receive(injection, now)));
  // Heard again once fewer than kDisturbedErrors failures lie within the window: 1 s after
  // the older of the last two (the second CRC failure, at 540 ms; the wrong length at 541).
  EXPECT_EQ(genuine(std::chrono::duration_cast<milliseconds>(kDisturbedWindow) - milliseconds(44), run),
            DecodeStatus::kStreamDisturbed);  // 1538 ms
  EXPECT_EQ(genuine(milliseconds(2), run), DecodeStatus::kOk);  // 1540 ms
  EXPECT_FALSE(rx.disturbed(CommandStream::kDrive, now));
  EXPECT_EQ(rx.counters(MessageType::kDriveCommand)[DecodeStatus::kStreamDisturbed], 3U);
  EXPECT_EQ(rx.counters(MessageType::kDriveCommand)[DecodeStatus::kCounterJump], 0U);
}

// A device babbling random frames on a node's command IDs: one in 256 passes the CRC-8, and
// some of those the alive counter. None may start anything (before the disturbed-stream rule, a
// calibration or an enable could start from such a frame: the count `passed` below); one that
// passes as a stop may stop the drive.
TEST(protocol_reject, RandomFramesOnTheCommandIdsAreNeverActedOn) {
  DaemonReceiver rx(2);
  std::mt19937_64 rng(20261202);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> length(0, 8);
  std::uniform_int_distribution<int> which(0, 2);
  nanoseconds now{0};
  std::uint64_t acted_on = 0;
  for (int i = 0; i < 300000; ++i) {
    now += microseconds(500);  // 2,000 frames a second
    CanFrame f;
    f.id = std::array<std::uint32_t, 3>{0x040, 0x050, 0x060}[static_cast<std::size_t>(which(rng))] + 2U;
    // Mostly the right length: a babbler that fills the command's DLC is the hard case.
    f.length = static_cast<std::uint8_t>(byte(rng) < 224 ? 8 : length(rng));
    for (auto& b : f.data) {
      b = static_cast<std::uint8_t>(byte(rng));
    }
    const DaemonInput in = rx.receive(f, now);
    const auto* drive = std::get_if<DriveCommand>(&in);
    const auto* calibration = std::get_if<CalibrationCommand>(&in);
    if (std::holds_alternative<InjectionCommand>(in) ||
        (drive != nullptr && drive->enable && drive->mode != DriveMode::kDisabled) ||
        (calibration != nullptr && calibration->action == CalibrationAction::kStart)) {
      ++acted_on;
    }
  }
  const DecodeCounters& c = rx.counters();
  const std::uint64_t passed = c[DecodeStatus::kStreamDisturbed];
  EXPECT_EQ(acted_on, 0U);
  // The rule was what held them back: random frames passed the CRC and the counter.
  EXPECT_GT(passed, 0U);
  EXPECT_GT(c[DecodeStatus::kBadCrc], 250000U);
}

TEST(protocol_reject, SenderDoesNotAdvanceOnInvalidFrames) {
  CommandSender tx(0);
  CanFrame f;
  DriveCommand bad;
  bad.torque_setpoint_Nm = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(tx.encode(bad, f), EncodeStatus::kInvalidValue);
  EXPECT_EQ(tx.next_counter(CommandStream::kDrive), 0);
  DriveCommand big;
  big.torque_setpoint_Nm = 5000;
  EXPECT_EQ(tx.encode(big, f), EncodeStatus::kSaturated);
  EXPECT_EQ(tx.next_counter(CommandStream::kDrive), 0) << "a saturated command is not sent: it takes no counter";
  DriveCommand fine;
  fine.torque_setpoint_Nm = 5;
  EXPECT_EQ(tx.encode(fine, f), EncodeStatus::kOk);
  EXPECT_EQ(tx.next_counter(CommandStream::kDrive), 1);
}

TEST(protocol_reject, AliveCounterStateMachine) {
  AliveCounterCheck check(1);
  EXPECT_EQ(check.check(3), DecodeStatus::kOk);
  EXPECT_EQ(check.check(4), DecodeStatus::kOk);
  EXPECT_EQ(check.check(6), DecodeStatus::kCounterJump);  // max delta 1: one lost frame is a jump
  EXPECT_EQ(check.check(7), DecodeStatus::kOk);
  EXPECT_EQ(check.check(7), DecodeStatus::kRepeatedCounter);
  check.reset();
  EXPECT_FALSE(check.synchronized());
  EXPECT_EQ(check.check(0), DecodeStatus::kOk);
  EXPECT_EQ(AliveCounterCheck(0).max_delta(), 1);
  EXPECT_EQ(AliveCounterCheck(15).max_delta(), 14);
  AliveCounterCheck wide(14);
  EXPECT_EQ(wide.check(0), DecodeStatus::kOk);
  EXPECT_EQ(wide.check(14), DecodeStatus::kOk);
  EXPECT_EQ(wide.check(13), DecodeStatus::kCounterJump);  // one step back is never accepted
}

TEST(protocol_reject, ResyncAcceptsTheNextFrameAsFirst) {
  DaemonReceiver rx(1);
  EXPECT_TRUE(std::holds_alternative<DriveCommand>(rx.receive(drive_frame(1, 3), nanoseconds{1})));
  EXPECT_TRUE(std::holds_alternative<Rejected>(rx.receive(drive_frame(1, 11), nanoseconds{2})));
  rx.resync(CommandStream::kDrive);
  EXPECT_TRUE(std::holds_alternative<DriveCommand>(rx.receive(drive_frame(1, 3), nanoseconds{3})));
}

TEST(protocol_reject, AgeTracksAcceptedFramesOnly) {
  DaemonReceiver rx(2);
  EXPECT_FALSE(rx.age(MessageType::kSensorSample, nanoseconds{0}).has_value());
  CanFrame f;
  ASSERT_EQ(encode(SensorSample{}, 2, f), EncodeStatus::kOk);
  EXPECT_TRUE(std::holds_alternative<SensorSample>(rx.receive(f, milliseconds(100))));
  EXPECT_EQ(rx.age(MessageType::kSensorSample, milliseconds(130)), milliseconds(30));
  f.fd = false;  // rejected frames do not refresh
  EXPECT_TRUE(std::holds_alternative<Rejected>(rx.receive(f, milliseconds(140))));
  EXPECT_EQ(rx.last_accepted(MessageType::kSensorSample), milliseconds(100));
  EXPECT_FALSE(rx.last_accepted(MessageType::kDriveCommand).has_value());
}

TEST(protocol_reject, PlantReceiver) {
  PlantReceiver rx(7);
  InverterCommand c;
  c.sequence = 99;
  c.duty = {1, 2, 3};
  c.enable = true;
  CanFrame f;
  ASSERT_EQ(encode(c, 7, f), EncodeStatus::kOk);
  const PlantInput in = rx.receive(f);
  ASSERT_TRUE(std::holds_alternative<InverterCommand>(in));
  EXPECT_EQ(std::get<InverterCommand>(in).duty, c.duty);
  CanFrame sample;
  ASSERT_EQ(encode(SensorSample{}, 7, sample), EncodeStatus::kOk);
  EXPECT_TRUE(std::holds_alternative<Rejected>(rx.receive(sample)));
  ASSERT_EQ(encode(c, 6, f), EncodeStatus::kOk);
  EXPECT_EQ(std::get<Rejected>(rx.receive(f)).reason, DecodeStatus::kWrongNode);
  EXPECT_EQ(rx.counters().accepted(), 1U);
  EXPECT_EQ(rx.counters()[DecodeStatus::kUnknownId], 1U);
  EXPECT_EQ(rx.counters()[DecodeStatus::kWrongNode], 1U);
}

TEST(protocol_codec, DecodeAnyAllTypesAndNodes) {
  CanFrame f;
  AnyDecoded d;
  ASSERT_EQ(encode(ThermalEstimate{}, 9, f), EncodeStatus::kOk);
  ASSERT_EQ(decode_any(f, d), DecodeStatus::kOk);
  EXPECT_EQ(d.type, MessageType::kThermalEstimate);
  EXPECT_EQ(d.node, 9);
  EXPECT_TRUE(std::holds_alternative<ThermalEstimate>(d.message));
  ASSERT_EQ(encode(CalibrationCommand{}, 3, 12, f), EncodeStatus::kOk);
  ASSERT_EQ(decode_any(f, d), DecodeStatus::kOk);
  EXPECT_EQ(d.type, MessageType::kCalibrationCommand);
  EXPECT_EQ(d.alive_counter, 12);
  EXPECT_EQ(d.message.index(), static_cast<std::size_t>(MessageType::kCalibrationCommand));
  f.id = 0x7F3;
  EXPECT_EQ(decode_any(f, d), DecodeStatus::kUnknownId);
}

// ---------------------------------------------------------------------------------------
// Receive filters
// ---------------------------------------------------------------------------------------

// The kernel's rule for a standard-ID filter (can_bus.hpp): id & mask == filter.id & mask.
bool admitted(std::span<const CanFilter> filters, std::uint32_t id) {
  for (const CanFilter& f : filters) {
    if (f.kind == CanIdKind::kStandard && (id & f.mask) == (f.id & f.mask)) {
      return true;
    }
  }
  return false;
}

TEST(protocol_filters, AdmitExactlyTheRolesFramesForItsNode) {
  for (const RoleDef& role : kRoles) {
    for (NodeId node = 0; node <= kMaxNodeId; ++node) {
      const FilterSet set = receive_filters(role.role, node);
      for (std::uint32_t id = 0; id <= 0x7FF; ++id) {
        const MessageDef* m = find_message(id);
        const bool wanted = m != nullptr && m->received_by(role.role) && node_of(id) == node;
        ASSERT_EQ(admitted(set.view(), id), wanted) << role.dbc_name << " node " << int{node} << " id " << id;
      }
    }
  }
  const FilterSet daemon = receive_filters(Role::kDaemon, 3);
  ASSERT_EQ(daemon.count, 4U);
  EXPECT_EQ(daemon.filters[0].id, 0x023U);
  EXPECT_EQ(daemon.filters[0].mask, 0x7FFU);
  EXPECT_EQ(daemon.filters[0].kind, CanIdKind::kStandard);
  EXPECT_EQ(receive_filters(Role::kPlant, 3).count, 1U);
  EXPECT_EQ(receive_filters(Role::kDaemon, 16).count, 0U);
}

// The daemon's publishing endpoint watches its own node's published identifiers: every
// watcher message it sends, not the fast loop's INVERTER_COMMAND (its control socket sends
// that, and the publishing socket hears its sibling's frames), nor another node's.
TEST(protocol_filters, PublishedFiltersAreTheRolesWatcherFramesOfItsNode) {
  const FilterSet set = published_filters(Role::kDaemon, 5);
  for (std::uint32_t id = 0; id <= 0x7FF; ++id) {
    const MessageDef* m = find_message(id);
    const bool wanted = m != nullptr && m->sender == Role::kDaemon && !m->received_by(Role::kPlant) &&
                        !m->received_by(Role::kDaemon) && node_of(id) == 5;
    ASSERT_EQ(admitted(set.view(), id), wanted) << id;
  }
  EXPECT_TRUE(admitted(set.view(), 0x145U)) << "HEARTBEAT of node 5";
  EXPECT_FALSE(admitted(set.view(), 0x015U)) << "INVERTER_COMMAND of node 5";
  EXPECT_FALSE(admitted(set.view(), 0x146U)) << "HEARTBEAT of node 6";
  EXPECT_EQ(published_filters(Role::kDaemon, 16).count, 0U);
}

TEST(protocol_filters, AllNodesVariant) {
  const FilterSet set = receive_filters_all_nodes(Role::kMonitor);
  for (std::uint32_t id = 0; id <= 0x7FF; ++id) {
    const MessageDef* m = find_message(id);
    EXPECT_EQ(admitted(set.view(), id), m != nullptr && m->received_by(Role::kMonitor)) << id;
  }
}

// ---------------------------------------------------------------------------------------
// Robustness: random frames never crash and every rejection is counted
// ---------------------------------------------------------------------------------------

TEST(protocol_fuzz, RandomFramesAreCountedNeverCrash) {
  std::mt19937_64 rng(20240611);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> len(0, 64);
  std::uniform_int_distribution<int> coin(0, 3);
  DaemonReceiver daemon(0);
  PlantReceiver plant(0);
  constexpr int kFrames = 200000;
  int any_ok = 0;
  for (int i = 0; i < kFrames; ++i) {
    CanFrame f;
    // Mostly our own IDs (so the deeper checks run), sometimes anything.
    if (coin(rng) != 0) {
      const MessageDef& m = kMessages[static_cast<std::size_t>(byte(rng)) % kMessageCount];
      f.id = m.can_id(static_cast<NodeId>(coin(rng) == 0 ? byte(rng) % 16 : 0));
      f.fd = coin(rng) == 0 ? !m.fd : m.fd;
      f.length = coin(rng) == 0 ? static_cast<std::uint8_t>(len(rng)) : m.length;
    } else {
      f.id = static_cast<std::uint32_t>(byte(rng) << 8 | byte(rng)) & 0x1FFF'FFFFU;
      f.extended = coin(rng) == 0;
      f.error = coin(rng) == 0 && coin(rng) == 0;
      f.fd = coin(rng) == 0;
      f.length = static_cast<std::uint8_t>(len(rng) + (coin(rng) == 0 ? 200 : 0));  // even impossible lengths
    }
    for (auto& b : f.data) {
      b = static_cast<std::uint8_t>(byte(rng));
    }
    (void)daemon.receive(f, nanoseconds{i});
    (void)plant.receive(f);
    AnyDecoded d;
    any_ok += decode_any(f, d) == DecodeStatus::kOk ? 1 : 0;
  }
  EXPECT_EQ(daemon.counters().accepted() + daemon.counters().rejected(), static_cast<std::uint64_t>(kFrames));
  EXPECT_EQ(plant.counters().accepted() + plant.counters().rejected(), static_cast<std::uint64_t>(kFrames));
  EXPECT_GT(daemon.counters().rejected(), static_cast<std::uint64_t>(kFrames / 2));
  for (std::size_t r = 1; r < kDecodeStatusCount; ++r) {
    if (static_cast<DecodeStatus>(r) == DecodeStatus::kStreamDisturbed) {
      continue;  // needs a command that passes by chance and starts something: about one frame in
                 // 80,000 on the command IDs alone (RandomFramesOnTheCommandIdsAreNeverActedOn)
    }
    EXPECT_GT(daemon.counters().by_status[r], 0U) << to_string(static_cast<DecodeStatus>(r));
  }
  EXPECT_GT(any_ok, 0);
}

}  // namespace
}  // namespace pmsm::hal::protocol
