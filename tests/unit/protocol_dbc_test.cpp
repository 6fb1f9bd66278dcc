// The DBC file against the codec: the committed can/pmsm-thermal.dbc, read with the
// independent DBC reader, decodes what the codec encodes (random valid values, every
// message), names every frame the codec knows and no other, and equals the generated file.
// The struct-field <-> signal-name pairs below are written out by hand on purpose: they are
// the independent statement of what each signal means.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/crc8.hpp"
#include "pmsm/tools/dbc.hpp"
#include "pmsm/tools/dbc_writer.hpp"
#include "pmsm/hal/protocol.hpp"

namespace pmsm::hal::protocol {
namespace {

const std::string kDbcPath = std::string(PMSM_SOURCE_DIR) + "/can/pmsm-thermal.dbc";
const std::string kDocsPath = std::string(PMSM_SOURCE_DIR) + "/docs/protocol.md";

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

const dbc::Database& committed_dbc() {
  static const dbc::Database db = dbc::load(kDbcPath);
  return db;
}

// ---------------------------------------------------------------------------------------
// Committed files are the generated ones
// ---------------------------------------------------------------------------------------

TEST(protocol_generated, CommittedDbcEqualsGenerated) {
  EXPECT_EQ(read_text(kDbcPath), generate_dbc(0))
      << "can/pmsm-thermal.dbc is out of date: cmake --build <build> --target pmsm-protocol-regen";
}

TEST(protocol_generated, CommittedDocsEqualGenerated) {
  const std::string docs = read_text(kDocsPath);
  ASSERT_NE(docs.find(kDocsBeginMarker), std::string::npos);
  EXPECT_EQ(docs, update_docs(docs))
      << "docs/protocol.md is out of date: cmake --build <build> --target pmsm-protocol-regen";
}

TEST(protocol_generated, OtherNodesDbcParsesWithOffsetIds) {
  const dbc::Database db = dbc::parse(generate_dbc(7));
  for (const MessageDef& m : kMessages) {
    const dbc::Message* dm = db.find(m.id_base + 7U, false);
    ASSERT_NE(dm, nullptr) << m.name;
    EXPECT_EQ(dm->name, m.name);
  }
}

// ---------------------------------------------------------------------------------------
// Structure: same frames, formats, lengths, senders, receivers
// ---------------------------------------------------------------------------------------

TEST(protocol_dbc, EveryCodecFrameIsInTheDbcAndViceVersa) {
  const dbc::Database& db = committed_dbc();
  std::set<std::uint32_t> codec_ids;
  for (const MessageDef& m : kMessages) {
    codec_ids.insert(m.can_id(0));
    const dbc::Message* dm = db.find(m.can_id(0), false);
    ASSERT_NE(dm, nullptr) << m.name << " is not in the DBC";
    EXPECT_EQ(dm->name, m.name);
    EXPECT_EQ(dm->length, m.length) << m.name;
    EXPECT_EQ(dm->fd, m.fd) << m.name;
    EXPECT_FALSE(dm->extended) << m.name;
    EXPECT_EQ(dm->sender, kRoles[static_cast<std::size_t>(m.sender)].dbc_name) << m.name;
    ASSERT_EQ(dm->signals.size(), m.signals.size()) << m.name;
  }
  for (const dbc::Message& dm : db.messages) {
    EXPECT_EQ(codec_ids.count(dm.id), 1U) << dm.name << " (" << dm.id << ") is in the DBC but not in the codec";
    const MessageDef* m = find_message(dm.id);
    ASSERT_NE(m, nullptr);
    for (const dbc::Signal& s : dm.signals) {
      for (const RoleDef& r : kRoles) {
        const bool listed = std::find(s.receivers.begin(), s.receivers.end(), r.dbc_name) != s.receivers.end();
        EXPECT_EQ(listed, m->received_by(r.role)) << dm.name << "." << s.name << " " << r.dbc_name;
      }
      EXPECT_EQ(s.byte_order, dbc::ByteOrder::kLittleEndian);
    }
  }
  EXPECT_EQ(db.messages.size(), kMessageCount);
  EXPECT_EQ(db.nodes, (std::vector<std::string>{"THERMALD", "PLANT", "SUPERVISOR", "MONITOR"}));
  EXPECT_EQ(db.version, kProtocolVersion);
}

TEST(protocol_dbc, NoSignalsOverlap) {
  for (const dbc::Message& m : committed_dbc().messages) {
    std::vector<bool> used(m.length * 8U, false);
    for (const dbc::Signal& s : m.signals) {
      for (unsigned b = s.start_bit; b < s.start_bit + s.length; ++b) {
        ASSERT_LT(b, used.size()) << m.name << "." << s.name;
        EXPECT_FALSE(used[b]) << m.name << "." << s.name << " overlaps at bit " << b;
        used[b] = true;
      }
    }
  }
}

// ---------------------------------------------------------------------------------------
// Agreement: codec encode -> DBC decode, random valid values
// ---------------------------------------------------------------------------------------

using Expected = std::vector<std::pair<std::string, double>>;

// Draws values from the DBC's own signal ranges (not the protocol tables).
class Picker {
 public:
  Picker(const dbc::Message& message, std::mt19937_64& rng) : message_(message), rng_(rng) {}

  const dbc::Signal& signal(const std::string& name) const {
    const dbc::Signal* s = message_.find_signal(name);
    if (s == nullptr) {
      ADD_FAILURE() << message_.name << " has no signal " << name;
      static const dbc::Signal none;
      return none;
    }
    return *s;
  }
  // A physical value in [min, max], off the raw grid by up to 0.4 steps.
  double value(const std::string& name) {
    const dbc::Signal& s = signal(name);
    const auto lo = static_cast<std::int64_t>(std::llround((s.minimum - s.offset) / s.factor));
    const auto hi = static_cast<std::int64_t>(std::llround((s.maximum - s.offset) / s.factor));
    std::uniform_int_distribution<std::int64_t> raw(lo, hi);
    std::int64_t r = raw(rng_);
    if (coin() && coin()) {
      r = coin() ? lo : hi;  // extremes
    }
    std::uniform_real_distribution<double> jitter(-0.4, 0.4);
    const double v = static_cast<double>(r) * s.factor + s.offset + jitter(rng_) * s.factor;
    return std::clamp(v, s.minimum, s.maximum);
  }
  std::int64_t integer(const std::string& name) {
    const dbc::Signal& s = signal(name);
    std::uniform_int_distribution<std::int64_t> raw(static_cast<std::int64_t>(s.minimum),
                                                    static_cast<std::int64_t>(s.maximum));
    return raw(rng_);
  }
  bool coin() { return uniform(0, 1) == 1; }
  int uniform(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng_); }

 private:
  const dbc::Message& message_;
  std::mt19937_64& rng_;
};

double b(bool v) { return v ? 1.0 : 0.0; }
template <class E>
double e(E v) {
  return static_cast<double>(static_cast<std::underlying_type_t<E>>(v));
}

template <class T>
struct Case {
  std::function<T(Picker&)> make;
  std::function<Expected(const T&)> expect;
};

void compare(const dbc::Message& dm, const dbc::DecodedFrame& decoded, const Expected& expected, int iteration) {
  ASSERT_FALSE(decoded.length_mismatch);
  ASSERT_FALSE(decoded.format_mismatch);
  std::map<std::string, double> got;
  for (const dbc::DecodedSignal& s : decoded.signals) {
    got[s.signal->name] = s.value;
  }
  std::set<std::string> checked;
  for (const auto& [name, value] : expected) {
    ASSERT_EQ(got.count(name), 1U) << dm.name << "." << name << " missing in the DBC decode";
    const dbc::Signal* s = dm.find_signal(name);
    EXPECT_NEAR(got[name], value, 0.5 * s->factor + 1e-9 * std::fabs(value))
        << dm.name << "." << name << " iteration " << iteration;
    checked.insert(name);
  }
  // Every DBC signal was checked (the E2E ones by the caller).
  for (const dbc::Signal& s : dm.signals) {
    if (s.name != "Crc" && s.name != "AliveCounter") {
      EXPECT_EQ(checked.count(s.name), 1U) << dm.name << "." << s.name << " not covered by the test";
    }
  }
}

template <class T>
void check_agreement(MessageType type, const Case<T>& c, int iterations = 3000) {
  const dbc::Database& db = committed_dbc();
  const MessageDef& def = message_def(type);
  std::mt19937_64 rng(0xC0FFEEU + static_cast<unsigned>(type));
  for (NodeId node : {NodeId{0}, NodeId{9}}) {
    const dbc::Database* use = &db;
    dbc::Database other;
    if (node != 0) {
      other = dbc::parse(generate_dbc(node));
      use = &other;
    }
    const dbc::Message* dm = use->find(def.can_id(node), false);
    ASSERT_NE(dm, nullptr) << def.name;
    Picker pick(*dm, rng);
    for (int i = 0; i < iterations; ++i) {
      const T message = c.make(pick);
      CanFrame f;
      std::uint8_t counter = 0;
      if constexpr (std::is_same_v<T, DriveCommand> || std::is_same_v<T, InjectionCommand> ||
                    std::is_same_v<T, CalibrationCommand>) {
        counter = static_cast<std::uint8_t>(i % 16);
        ASSERT_EQ(encode(message, node, counter, f), EncodeStatus::kOk) << def.name << " " << i;
      } else {
        ASSERT_EQ(encode(message, node, f), EncodeStatus::kOk) << def.name << " " << i;
      }
      const std::optional<dbc::DecodedFrame> decoded = dbc::decode(*use, f);
      ASSERT_TRUE(decoded.has_value()) << def.name;
      Expected expected = c.expect(message);
      if (def.e2e) {
        // The CRC recomputed here from the DBC's view of the frame: ID low, ID high, bytes 1..7.
        std::array<std::uint8_t, 9> covered{static_cast<std::uint8_t>(f.id & 0xFFU),
                                            static_cast<std::uint8_t>(f.id >> 8U)};
        std::copy(f.data.begin() + 1, f.data.begin() + 8, covered.begin() + 2);
        expected.emplace_back("Crc", crc8_sae_j1850(covered));
        expected.emplace_back("AliveCounter", counter);
      }
      compare(*dm, *decoded, expected, i);
      if (::testing::Test::HasFatalFailure() || ::testing::Test::HasNonfatalFailure()) {
        return;  // one failing iteration tells enough
      }
      // And the codec reads back what it wrote.
      AnyDecoded back;
      ASSERT_EQ(decode_any(f, back), DecodeStatus::kOk) << def.name;
    }
  }
}

TEST(protocol_agreement, InverterCommand) {
  check_agreement<InverterCommand>(MessageType::kInverterCommand, {
      [](Picker& p) {
        InverterCommand m;
        m.sequence = static_cast<std::uint32_t>(p.integer("Sequence"));
        // Duty signals are fractions in the DBC; the codec's field is the raw code.
        for (auto& d : m.duty) {
          d = static_cast<std::uint16_t>(p.uniform(0, 65535));
        }
        m.enable = p.coin();
        return m;
      },
      [](const InverterCommand& m) {
        return Expected{{"Sequence", m.sequence}, {"DutyA", m.duty[0] / 65535.0}, {"DutyB", m.duty[1] / 65535.0},
                        {"DutyC", m.duty[2] / 65535.0}, {"Enable", b(m.enable)}};
      }});
}

TEST(protocol_agreement, SensorSample) {
  check_agreement<SensorSample>(MessageType::kSensorSample, {
      [](Picker& p) {
        SensorSample m;
        m.sequence = static_cast<std::uint32_t>(p.integer("Sequence"));
        m.phase_current_adc = {static_cast<std::int16_t>(p.integer("PhaseCurrentAdcA")),
                               static_cast<std::int16_t>(p.integer("PhaseCurrentAdcB")),
                               static_cast<std::int16_t>(p.integer("PhaseCurrentAdcC"))};
        m.encoder_count = static_cast<std::uint16_t>(p.integer("EncoderCount"));
        m.dc_bus_adc = static_cast<std::uint16_t>(p.integer("DcBusAdc"));
        m.phase_voltage_adc = {static_cast<std::int16_t>(p.integer("PhaseVoltageAdcA")),
                               static_cast<std::int16_t>(p.integer("PhaseVoltageAdcB")),
                               static_cast<std::int16_t>(p.integer("PhaseVoltageAdcC"))};
        m.flags = static_cast<std::uint8_t>((p.coin() ? kSensorOutputEnabled : 0) |
                                            (p.coin() ? kSensorPhaseVoltageValid : 0) |
                                            (p.coin() ? kSensorHardwareOvercurrent : 0) |
                                            (p.coin() ? kSensorAmbientValid : 0));
        if ((m.flags & kSensorAmbientValid) != 0U) {
          m.ambient_centi_C = static_cast<std::int16_t>(std::lround(100.0 * p.value("AmbientTemp")));
        }
        m.pwm_period_code = static_cast<std::uint16_t>(std::lround(4.0 * p.value("PwmPeriod")));
        return m;
      },
      [](const SensorSample& m) {
        return Expected{{"Sequence", m.sequence},
                        {"PhaseCurrentAdcA", m.phase_current_adc[0]},
                        {"PhaseCurrentAdcB", m.phase_current_adc[1]},
                        {"PhaseCurrentAdcC", m.phase_current_adc[2]},
                        {"EncoderCount", m.encoder_count},
                        {"DcBusAdc", m.dc_bus_adc},
                        {"PhaseVoltageAdcA", m.phase_voltage_adc[0]},
                        {"PhaseVoltageAdcB", m.phase_voltage_adc[1]},
                        {"PhaseVoltageAdcC", m.phase_voltage_adc[2]},
                        {"OutputEnabled", b((m.flags & kSensorOutputEnabled) != 0)},
                        {"PhaseVoltageValid", b((m.flags & kSensorPhaseVoltageValid) != 0)},
                        {"HardwareOvercurrent", b((m.flags & kSensorHardwareOvercurrent) != 0)},
                        {"AmbientValid", b((m.flags & kSensorAmbientValid) != 0)},
                        {"PwmPeriod", 0.25 * m.pwm_period_code},
                        {"AmbientTemp", 0.01 * m.ambient_centi_C}};
      }});
}

TEST(protocol_agreement, DriveCommand) {
  check_agreement<DriveCommand>(MessageType::kDriveCommand, {
      [](Picker& p) {
        DriveCommand m;
        m.enable = p.coin();
        m.mode = static_cast<DriveMode>(p.integer("Mode"));
        m.speed_setpoint_rad_s = p.value("SpeedSetpoint");
        m.torque_setpoint_Nm = p.value("TorqueSetpoint");
        return m;
      },
      [](const DriveCommand& m) {
        return Expected{{"Enable", b(m.enable)}, {"Mode", e(m.mode)}, {"SpeedSetpoint", m.speed_setpoint_rad_s},
                        {"TorqueSetpoint", m.torque_setpoint_Nm}};
      }});
}

TEST(protocol_agreement, InjectionCommand) {
  check_agreement<InjectionCommand>(MessageType::kInjectionCommand, {
      [](Picker& p) {
        InjectionCommand m;
        m.method = static_cast<InjectionMethod>(p.integer("Method"));
        m.amplitude_A = p.value("Amplitude");
        m.interval_s = p.value("Interval");
        m.request_now = p.coin();
        return m;
      },
      [](const InjectionCommand& m) {
        return Expected{{"Method", e(m.method)}, {"Amplitude", m.amplitude_A}, {"Interval", m.interval_s},
                        {"RequestNow", b(m.request_now)}};
      }});
}

TEST(protocol_agreement, CalibrationCommand) {
  check_agreement<CalibrationCommand>(MessageType::kCalibrationCommand, {
      [](Picker& p) {
        CalibrationCommand m;
        m.action = static_cast<CalibrationAction>(p.integer("Action"));
        m.known_temp_C = p.value("KnownTemp");
        return m;
      },
      [](const CalibrationCommand& m) {
        return Expected{{"Action", e(m.action)}, {"KnownTemp", m.known_temp_C}};
      }});
}

TEST(protocol_agreement, Fault) {
  check_agreement<FaultReport>(MessageType::kFault, {
      [](Picker& p) {
        FaultReport m;
        m.code = static_cast<FaultCode>(p.integer("Code"));
        m.active = p.coin();
        m.occurrence_count = static_cast<std::uint32_t>(p.integer("OccurrenceCount"));
        m.last_change_uptime_s = p.value("LastChangeUptime");
        return m;
      },
      [](const FaultReport& m) {
        return Expected{{"Code", e(m.code)}, {"Active", b(m.active)}, {"OccurrenceCount", m.occurrence_count},
                        {"LastChangeUptime", m.last_change_uptime_s}};
      }});
}

TEST(protocol_agreement, DriveStatus) {
  check_agreement<DriveStatus>(MessageType::kDriveStatus, {
      [](Picker& p) {
        DriveStatus m;
        m.state = static_cast<DriveState>(p.integer("State"));
        m.limiting_reasons = static_cast<std::uint8_t>(p.uniform(0, 31));
        m.current_limit_A = p.value("CurrentLimit");
        m.time_to_limit_valid = p.coin();
        m.time_to_limit_s = p.value("TimeToLimit");
        m.motion_valid = p.coin();
        m.speed_rad_s = p.value("Speed");
        m.torque_Nm = p.value("Torque");
        return m;
      },
      [](const DriveStatus& m) {
        return Expected{{"State", e(m.state)},
                        {"LimitWindingTemp", b((m.limiting_reasons & kLimitReasonWindingTemp) != 0)},
                        {"LimitMagnetTemp", b((m.limiting_reasons & kLimitReasonMagnetTemp) != 0)},
                        {"LimitVoltage", b((m.limiting_reasons & kLimitReasonVoltage) != 0)},
                        {"LimitCurrent", b((m.limiting_reasons & kLimitReasonCurrent) != 0)},
                        {"LimitSpeed", b((m.limiting_reasons & kLimitReasonSpeed) != 0)},
                        {"CurrentLimit", m.current_limit_A},
                        {"TimeToLimit", m.time_to_limit_valid ? m.time_to_limit_s : 0.0},
                        {"MotionValid", b(m.motion_valid)},
                        {"TimeToLimitValid", b(m.time_to_limit_valid)},
                        {"Speed", m.motion_valid ? m.speed_rad_s : 0.0},
                        {"Torque", m.motion_valid ? m.torque_Nm : 0.0}};
      }});
}

TEST(protocol_agreement, ThermalEstimate) {
  check_agreement<ThermalEstimate>(MessageType::kThermalEstimate, {
      [](Picker& p) {
        ThermalEstimate m;
        m.valid = p.coin() || p.coin();
        m.winding_temp_C = p.value("WindingTemp");
        m.winding_temp_sigma_C = p.value("WindingTempSigma");
        m.magnet_valid = p.coin();
        m.magnet_temp_C = p.value("MagnetTemp");
        m.magnet_temp_sigma_C = p.value("MagnetTempSigma");
        m.calibrated = p.coin();
        m.derating_active = p.coin();
        m.stale = p.coin();
        m.calibration_result = static_cast<CalibrationResult>(p.integer("CalibrationResult"));
        m.calibrating = p.coin();
        return m;
      },
      [](const ThermalEstimate& m) {
        return Expected{{"WindingTemp", m.valid ? m.winding_temp_C : 0.0},
                        {"WindingTempSigma", m.valid ? m.winding_temp_sigma_C : 0.0},
                        {"MagnetTemp", m.magnet_valid ? m.magnet_temp_C : 0.0},
                        {"MagnetTempSigma", m.magnet_valid ? m.magnet_temp_sigma_C : 0.0},
                        {"Valid", b(m.valid)},
                        {"Calibrated", b(m.calibrated)},
                        {"DeratingActive", b(m.derating_active)},
                        {"Stale", b(m.stale)},
                        {"MagnetValid", b(m.magnet_valid)},
                        {"CalibrationResult", e(m.calibration_result)},
                        {"Calibrating", b(m.calibrating)}};
      }});
}

TEST(protocol_agreement, ResistanceEstimate) {
  check_agreement<ResistanceEstimate>(MessageType::kResistanceEstimate, {
      [](Picker& p) {
        ResistanceEstimate m;
        m.valid = p.coin() || p.coin();
        m.rs_ohm = p.value("Rs");
        m.rs_sigma_ohm = p.value("RsSigma");
        m.rs0_ohm = p.value("Rs0");
        m.estimate_count = static_cast<std::uint16_t>(p.integer("EstimateCount"));
        return m;
      },
      [](const ResistanceEstimate& m) {
        return Expected{{"Rs", m.valid ? m.rs_ohm : 0.0},
                        {"RsSigma", m.valid ? m.rs_sigma_ohm : 0.0},
                        {"Rs0", m.rs0_ohm},
                        {"Valid", b(m.valid)},
                        {"EstimateCount", m.estimate_count}};
      }});
}

TEST(protocol_agreement, InjectionReport) {
  check_agreement<InjectionReport>(MessageType::kInjectionReport, {
      [](Picker& p) {
        InjectionReport m;
        m.injection_count = static_cast<std::uint8_t>(p.integer("InjectionCount"));
        m.method = static_cast<InjectionMethod>(p.integer("Method"));
        m.result = static_cast<InjectionResult>(p.integer("Result"));
        m.amplitude_A = p.value("Amplitude");
        m.rs_valid = p.coin();
        m.measured_rs_ohm = p.value("MeasuredRs");
        m.speed_change_valid = p.coin();
        m.speed_change_rad_s = p.value("SpeedChange");
        return m;
      },
      [](const InjectionReport& m) {
        return Expected{{"InjectionCount", m.injection_count},
                        {"Method", e(m.method)},
                        {"Result", e(m.result)},
                        {"RsValid", b(m.rs_valid)},
                        {"Amplitude", m.amplitude_A},
                        {"MeasuredRs", m.rs_valid ? m.measured_rs_ohm : 0.0},
                        {"SpeedChangeValid", b(m.speed_change_valid)},
                        {"SpeedChange", m.speed_change_valid ? m.speed_change_rad_s : 0.0}};
      }});
}

TEST(protocol_agreement, Heartbeat) {
  check_agreement<Heartbeat>(MessageType::kHeartbeat, {
      [](Picker& p) {
        Heartbeat m;
        m.uptime_s = p.value("Uptime");
        m.state = static_cast<DriveState>(p.integer("State"));
        m.ambient_source = static_cast<AmbientSource>(p.integer("AmbientSource"));
        m.counter = static_cast<std::uint8_t>(p.integer("Counter"));
        m.deadline_misses = static_cast<std::uint32_t>(p.integer("DeadlineMisses"));
        return m;
      },
      [](const Heartbeat& m) {
        return Expected{{"Uptime", m.uptime_s}, {"State", e(m.state)}, {"AmbientSource", e(m.ambient_source)},
                        {"Counter", m.counter}, {"DeadlineMisses", m.deadline_misses}};
      }});
}

TEST(protocol_agreement, ReceiveStatus) {
  check_agreement<ReceiveStatus>(MessageType::kReceiveStatus, {
      [](Picker& p) {
        ReceiveStatus m;
        m.last_rejection = static_cast<std::uint8_t>(p.integer("LastRejection"));
        m.last_rejected_id = static_cast<std::uint16_t>(p.integer("LastRejectedId"));
        m.commands_accepted = static_cast<std::uint64_t>(p.integer("CommandsAccepted"));
        m.rejected_crc = static_cast<std::uint64_t>(p.integer("RejectedCrc"));
        m.rejected_counter = static_cast<std::uint64_t>(p.integer("RejectedCounter"));
        m.rejected_range = static_cast<std::uint64_t>(p.integer("RejectedRange"));
        m.rejected_format = static_cast<std::uint64_t>(p.integer("RejectedFormat"));
        m.rejected_other = static_cast<std::uint64_t>(p.integer("RejectedOther"));
        return m;
      },
      [](const ReceiveStatus& m) {
        return Expected{{"LastRejection", m.last_rejection},    {"LastRejectedId", m.last_rejected_id},
                        {"CommandsAccepted", m.commands_accepted}, {"RejectedCrc", m.rejected_crc},
                        {"RejectedCounter", m.rejected_counter}, {"RejectedRange", m.rejected_range},
                        {"RejectedFormat", m.rejected_format},   {"RejectedOther", m.rejected_other}};
      }});
}

TEST(protocol_agreement, LoopTiming) {
  check_agreement<LoopTiming>(MessageType::kLoopTiming, {
      [](Picker& p) {
        LoopTiming m;
        m.latency_p50_us = p.value("LatencyP50");
        m.latency_p99_us = p.value("LatencyP99");
        m.latency_max_us = p.value("LatencyMax");
        m.periods = static_cast<std::uint32_t>(p.integer("Periods"));
        m.deadline_misses = static_cast<std::uint32_t>(p.integer("DeadlineMisses"));
        return m;
      },
      [](const LoopTiming& m) {
        return Expected{{"LatencyP50", m.latency_p50_us}, {"LatencyP99", m.latency_p99_us},
                        {"LatencyMax", m.latency_max_us}, {"Periods", m.periods},
                        {"DeadlineMisses", m.deadline_misses}};
      }});
}

TEST(protocol_agreement, TruthThermal) {
  check_agreement<TruthThermal>(MessageType::kTruthThermal, {
      [](Picker& p) {
        TruthThermal m;
        m.winding_temp_C = p.value("WindingTemp");
        m.housing_temp_C = p.value("HousingTemp");
        m.magnet_temp_C = p.value("MagnetTemp");
        m.ambient_temp_C = p.value("AmbientTemp");
        return m;
      },
      [](const TruthThermal& m) {
        return Expected{{"WindingTemp", m.winding_temp_C}, {"HousingTemp", m.housing_temp_C},
                        {"MagnetTemp", m.magnet_temp_C}, {"AmbientTemp", m.ambient_temp_C}};
      }});
}

TEST(protocol_agreement, TruthElectrical) {
  check_agreement<TruthElectrical>(MessageType::kTruthElectrical, {
      [](Picker& p) {
        TruthElectrical m;
        m.rs_ohm = p.value("Rs");
        m.speed_rad_s = p.value("Speed");
        m.torque_Nm = p.value("Torque");
        m.load_torque_Nm = p.value("LoadTorque");
        return m;
      },
      [](const TruthElectrical& m) {
        return Expected{{"Rs", m.rs_ohm}, {"Speed", m.speed_rad_s}, {"Torque", m.torque_Nm},
                        {"LoadTorque", m.load_torque_Nm}};
      }});
}

TEST(protocol_agreement, PlantStatus) {
  check_agreement<PlantStatus>(MessageType::kPlantStatus, {
      [](Picker& p) {
        PlantStatus m;
        m.mode = static_cast<PlantMode>(p.integer("Mode"));
        m.output_enabled = p.coin();
        m.command_timeout_tripped = p.coin();
        m.late_commands = static_cast<std::uint32_t>(p.integer("LateCommands"));
        m.missing_commands = static_cast<std::uint32_t>(p.integer("MissingCommands"));
        m.simulated_time_s = p.value("SimulatedTime");
        return m;
      },
      [](const PlantStatus& m) {
        return Expected{{"Mode", e(m.mode)},
                        {"OutputEnabled", b(m.output_enabled)},
                        {"CommandTimeoutTripped", b(m.command_timeout_tripped)},
                        {"LateCommands", m.late_commands},
                        {"MissingCommands", m.missing_commands},
                        {"SimulatedTime", m.simulated_time_s}};
      }});
}

// Value tables in the DBC carry the same labels as the C++ enums' tables.
TEST(protocol_agreement, ValueTables) {
  const dbc::Database& db = committed_dbc();
  for (const MessageDef& m : kMessages) {
    const dbc::Message* dm = db.find(m.can_id(0), false);
    ASSERT_NE(dm, nullptr);
    for (const SignalDef& s : m.signals) {
      const dbc::Signal* ds = dm->find_signal(s.name);
      ASSERT_NE(ds, nullptr);
      ASSERT_EQ(ds->values.size(), s.values.size()) << m.name << "." << s.name;
      for (std::size_t i = 0; i < s.values.size(); ++i) {
        EXPECT_EQ(ds->values[i].value, s.values[i].value);
        EXPECT_EQ(ds->values[i].label, s.values[i].label);
      }
    }
  }
}

// ---------------------------------------------------------------------------------------
// The DBC reader on its own
// ---------------------------------------------------------------------------------------

constexpr const char* kSmallDbc = R"(VERSION "t"
NS_ :
	CM_
	BA_DEF_

BS_: 500 : 12,34

BU_: A B C
VAL_TABLE_ OnOff 1 "On" 0 "Off" ;

BO_ 291 MOTO: 8 A
 SG_ Big : 7|16@0+ (1,0) [0|65535] "" B
 SG_ BigSigned : 23|12@0- (0.5,-1) [-1025|1023] "V" B C
 SG_ Small : 24|4@1- (1,0) [-8|7] "" Vector__XXX

BO_ 2147484000 EXT: 8 B
 SG_ Mux M : 0|8@1+ (1,0) [0|255] "" A
 SG_ WhenOne m1 : 8|16@1+ (0.1,0) [0|6553.5] "A" A
 SG_ WhenTwo m2 : 8|16@1- (1,0) [-32768|32767] "" A
 SG_ Always : 24|32@1+ (1,0) [0|0] "" A

BO_ 512 FLT: 12 C
 SG_ F : 0|32@1- (1,0) [0|0] "" A
 SG_ D : 32|64@1- (2,1) [0|0] "" A

BO_TX_BU_ 291 : A,C;
CM_ "database comment";
CM_ BO_ 291 "a
multi-line comment";
CM_ SG_ 291 Big "big endian";
BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","J1939PG","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","StandardCAN_FD","ExtendedCAN_FD";
BA_DEF_ "BusType" STRING ;
BA_DEF_DEF_ "VFrameFormat" "StandardCAN";
BA_ "VFrameFormat" BO_ 512 14;
BA_ "BusType" "CAN FD";
VAL_ 2147484000 Mux 1 "ONE" 2 "TWO" ;
SIG_VALTYPE_ 512 F : 1;
SIG_VALTYPE_ 512 D : 2;
SG_MUL_VAL_ 2147484000 WhenOne Mux 1-1;
// a comment line
)";

TEST(protocol_dbc_reader, ParsesTheFormat) {
  const dbc::Database db = dbc::parse(kSmallDbc);
  EXPECT_EQ(db.version, "t");
  EXPECT_EQ(db.nodes, (std::vector<std::string>{"A", "B", "C"}));
  EXPECT_EQ(db.comment, "database comment");
  ASSERT_EQ(db.messages.size(), 3U);
  const dbc::Message* moto = db.find("MOTO");
  ASSERT_NE(moto, nullptr);
  EXPECT_EQ(moto->id, 291U);
  EXPECT_FALSE(moto->fd);
  EXPECT_EQ(moto->comment, "a\nmulti-line comment");
  EXPECT_EQ(moto->extra_senders, (std::vector<std::string>{"A", "C"}));
  const dbc::Signal* big = moto->find_signal("BigSigned");
  ASSERT_NE(big, nullptr);
  EXPECT_EQ(big->byte_order, dbc::ByteOrder::kBigEndian);
  EXPECT_TRUE(big->is_signed);
  EXPECT_EQ(big->receivers, (std::vector<std::string>{"B", "C"}));
  EXPECT_EQ(moto->find_signal("Small")->receivers.size(), 0U);
  EXPECT_EQ(moto->find_signal("Big")->comment, "big endian");
  const dbc::Message* ext = db.find(0x160, true);
  ASSERT_NE(ext, nullptr);
  EXPECT_EQ(ext->name, "EXT");
  EXPECT_EQ(ext->find_signal("Mux")->values.size(), 2U);
  const dbc::Message* flt = db.find(512, false);
  ASSERT_NE(flt, nullptr);
  EXPECT_TRUE(flt->fd);
  EXPECT_EQ(flt->find_signal("F")->value_type, dbc::ValueType::kFloat32);
}

TEST(protocol_dbc_reader, MotorolaAndSignedDecoding) {
  const dbc::Database db = dbc::parse(kSmallDbc);
  CanFrame f;
  f.id = 291;
  f.length = 8;
  // Big: bytes 0..1 big-endian = 0x1234. BigSigned: 12 bits from bit 23 (MSB of byte 2)
  // = byte 2 and the high nibble of byte 3 = 0xFFE -> -2 -> -2 * 0.5 - 1 = -2.
  // Small: Intel 4 bits from bit 24 = low nibble of byte 3 = 0x9 -> -7.
  f.data = {0x12, 0x34, 0xFF, 0xE9, 0, 0, 0, 0};
  const auto d = dbc::decode(db, f);
  ASSERT_TRUE(d.has_value());
  ASSERT_EQ(d->signals.size(), 3U);
  EXPECT_EQ(d->signals[0].raw, 0x1234);
  EXPECT_EQ(d->signals[1].raw, -2);
  EXPECT_DOUBLE_EQ(d->signals[1].value, -2.0);
  EXPECT_EQ(d->signals[2].raw, -7);
  EXPECT_FALSE(d->length_mismatch);
}

TEST(protocol_dbc_reader, MultiplexingAndFloats) {
  const dbc::Database db = dbc::parse(kSmallDbc);
  CanFrame f;
  f.id = 0x160;
  f.extended = true;
  f.length = 8;
  f.data = {2, 0xFE, 0xFF, 1, 0, 0, 0, 0};
  auto d = dbc::decode(db, f);
  ASSERT_TRUE(d.has_value());
  ASSERT_EQ(d->signals.size(), 3U);  // Mux, WhenTwo, Always
  EXPECT_EQ(d->signals[0].label->label, "TWO");
  EXPECT_EQ(d->signals[1].signal->name, "WhenTwo");
  EXPECT_EQ(d->signals[1].raw, -2);
  EXPECT_EQ(dbc::format_single_line(*d), "EXT(Mux: TWO, WhenTwo: -2, Always: 1)");

  CanFrame g;
  g.id = 512;
  g.fd = true;
  g.length = 12;
  const float fv = -1.5F;
  const double dv = 1234.5;
  std::memcpy(g.data.data(), &fv, 4);
  std::memcpy(g.data.data() + 4, &dv, 8);
  d = dbc::decode(db, g);
  ASSERT_TRUE(d.has_value());
  EXPECT_DOUBLE_EQ(d->signals[0].value, -1.5);
  EXPECT_DOUBLE_EQ(d->signals[1].value, 2 * 1234.5 + 1);
}

TEST(protocol_dbc_reader, ShortFramesDecodeWhatFits) {
  const dbc::Database db = dbc::parse(kSmallDbc);
  CanFrame f;
  f.id = 291;
  f.length = 2;
  f.data = {0x12, 0x34};
  const auto d = dbc::decode(db, f);
  ASSERT_TRUE(d.has_value());
  EXPECT_TRUE(d->length_mismatch);
  ASSERT_EQ(d->signals.size(), 1U);
  EXPECT_EQ(d->signals[0].signal->name, "Big");
  CanFrame unknown;
  unknown.id = 0x7FF;
  EXPECT_FALSE(dbc::decode(db, unknown).has_value());
}

void expect_error_at(const std::string& text, int line, const std::string& fragment) {
  try {
    (void)dbc::parse(text);
    ADD_FAILURE() << "no error for:\n" << text;
  } catch (const dbc::ParseError& e) {
    EXPECT_EQ(e.line(), line) << e.what();
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("line " + std::to_string(line)), std::string::npos) << e.what();
  }
}

TEST(protocol_dbc_reader, ErrorsNameTheLine) {
  const std::string head = "VERSION \"\"\nBU_: A\nBO_ 1 M: 8 A\n";  // lines 1-3
  expect_error_at(head + " SG_ S : 0|8@1+ (1,0) [0|1] A\n", 4, "unit");
  expect_error_at(head + " SG_ S : 0 8@1+ (1,0) [0|1] \"\" A\n", 4, "'|'");
  expect_error_at(head + " SG_ S : 0|8@2+ (1,0) [0|1] \"\" A\n", 4, "byte order");
  expect_error_at(head + " SG_ S : 60|8@1+ (1,0) [0|1] \"\" A\n", 4, "does not fit");
  expect_error_at(head + " SG_ S : 0|8@1+ (1,0) [0|1] \"\" A\n SG_ S : 8|8@1+ (1,0) [0|1] \"\" A\n", 5, "duplicate");
  expect_error_at(head + "BO_ 1 N: 8 A\n", 4, "duplicate message id");
  expect_error_at("VERSION \"\"\n\n SG_ S : 0|8@1+ (1,0) [0|1] \"\" A\n", 3, "outside a message");
  expect_error_at(head + "CM_ BO_ 1 \"unterminated;\n\n", 4, "unterminated string");
  // A label printed to a terminal carries no escape (a DBC's "\x1b[31mRUNNING" coloured decode's
  // output); a comment's line breaks and tabs stay.
  expect_error_at(head + " SG_ S : 0|8@1+ (1,0) [0|1] \"\x1b[31mV\" A\n", 4, "a control character (0x1b) in a quoted string");
  expect_error_at(head + "VAL_ 1 S 1 \"RUN\xc2\x9bNING\" ;\n", 4, "a control character (0x9b) in a quoted string");
  expect_error_at(head + "VAL_ 99 S 1 \"x\" ;\n", 4, "unknown message");
  expect_error_at(head + "WHATEVER_ 1;\n", 4, "unknown keyword");
  expect_error_at(head + "BO_ 4096 BIG: 8 A\n", 4, "exceeds 0x7FF");
  expect_error_at(head + "BA_DEF_ BO_ \"X\" INT 0 1\n", 5, "';'");
  expect_error_at(head + "  $\n", 4, "unexpected character");
  expect_error_at(head + " SG_ S : 0|8@1+ (1x,0) [0|1] \"\" A\n", 4, "malformed number");
}

TEST(protocol_dbc_reader, LoadReportsMissingFile) {
  EXPECT_THROW((void)dbc::load("/nonexistent/file.dbc"), dbc::ParseError);
}

// Mutated DBC text: parses or throws ParseError, never crashes.
TEST(protocol_fuzz, MutatedDbcNeverCrashes) {
  const std::string original = generate_dbc(0);
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<std::size_t> pos(0, original.size() - 1);
  std::uniform_int_distribution<int> ch(0, 127);
  int parsed = 0;
  int errors = 0;
  for (int i = 0; i < 1500; ++i) {
    std::string text = original;
    const int edits = 1 + (i % 4);
    for (int k = 0; k < edits; ++k) {
      const std::size_t p = pos(rng);
      switch (ch(rng) % 3) {
        case 0: text[p] = static_cast<char>(ch(rng)); break;
        case 1: text.erase(p, 1 + static_cast<std::size_t>(ch(rng) % 20)); break;
        default: text.insert(p, 1, static_cast<char>(ch(rng))); break;
      }
    }
    try {
      const dbc::Database db = dbc::parse(text);
      ++parsed;
      CanFrame f;
      f.length = 64;
      for (const dbc::Message& m : db.messages) {
        f.id = m.id;
        f.extended = m.extended;
        (void)dbc::decode(db, f);
      }
    } catch (const dbc::ParseError&) {
      ++errors;
    }
  }
  EXPECT_GT(errors, 0);
  EXPECT_GT(parsed, 0);
}

}  // namespace
}  // namespace pmsm::hal::protocol
