// candump line parsing (default, -a, -ta, -tz, -tA, -x, -L; classic and CAN FD), the
// cantools-like formatter, and decoding protocol frames from a log with the DBC reader.
#include <gtest/gtest.h>

#include <fstream>
#include <random>
#include <set>
#include <variant>
#include <string>
#include <vector>

#include "pmsm/tools/candump.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/tools/dbc.hpp"
#include "pmsm/tools/dbc_writer.hpp"

namespace pmsm::hal::candump {
namespace {

using std::chrono::nanoseconds;

const std::string kDataDir = std::string(PMSM_SOURCE_DIR) + "/tests/unit/data/candump/";

std::vector<std::string> read_lines(const std::string& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) {
    lines.push_back(line);
  }
  return lines;
}

Record parse_ok(std::string_view line) {
  const ParseResult r = parse_line(line);
  EXPECT_TRUE(r.ok()) << "'" << line << "': " << r.error;
  return r.ok() ? *r.record : Record{};
}

// ---------------------------------------------------------------------------------------
// Single lines
// ---------------------------------------------------------------------------------------

TEST(protocol_candump, DefaultClassic) {
  const Record r = parse_ok("  vcan0  123   [4]  DE AD BE EF");
  EXPECT_EQ(r.format, Format::kDefault);
  EXPECT_FALSE(r.timestamp.has_value());
  EXPECT_EQ(r.interface, "vcan0");
  EXPECT_EQ(r.frame.id, 0x123U);
  EXPECT_FALSE(r.frame.fd);
  EXPECT_FALSE(r.frame.extended);
  ASSERT_EQ(r.frame.length, 4);
  EXPECT_EQ(r.frame.data[0], 0xDE);
  EXPECT_EQ(r.frame.data[3], 0xEF);
}

TEST(protocol_candump, DefaultFdHasTwoDigitLength) {
  const Record r = parse_ok("  vcan0       123  [08]  DE AD BE EF 00 11 22 33");
  EXPECT_TRUE(r.frame.fd);
  EXPECT_EQ(r.frame.length, 8);
  const Record empty = parse_ok("  vcan0       043  [00] ");
  EXPECT_TRUE(empty.frame.fd);
  EXPECT_EQ(empty.frame.length, 0);
  const Record classic_empty = parse_ok("  vcan0       7FF   [0] ");
  EXPECT_FALSE(classic_empty.frame.fd);
}

TEST(protocol_candump, TimestampedAbsoluteAndRelative) {
  Record r = parse_ok(" (1795248289.854339)  vcan0  123   [4]  DE AD BE EF");
  EXPECT_EQ(r.format, Format::kTimestamped);
  ASSERT_TRUE(r.timestamp.has_value());
  EXPECT_EQ(r.timestamp->count(), 1795248289854339000LL);
  r = parse_ok(" (000.021658)  vcan0  12345678   [8]  00 11 22 33 44 55 66 77");
  EXPECT_EQ(r.timestamp->count(), 21658000);
  EXPECT_TRUE(r.frame.extended);
  EXPECT_EQ(r.frame.id, 0x12345678U);
  r = parse_ok(" (2026-11-21 08:04:49.854339)  vcan0  123   [4]  DE AD BE EF");
  EXPECT_EQ(r.timestamp->count(), 1795248289854339000LL);
}

TEST(protocol_candump, LogFormat) {
  Record r = parse_ok("(1795248289.854339) vcan0 123#DEADBEEF");
  EXPECT_EQ(r.format, Format::kLog);
  EXPECT_EQ(r.timestamp->count(), 1795248289854339000LL);
  EXPECT_EQ(r.frame.length, 4);
  EXPECT_FALSE(r.frame.fd);
  r = parse_ok("(1795248289.886426) vcan0 123##5DEADBEEF00112233");
  EXPECT_TRUE(r.frame.fd);
  EXPECT_TRUE(r.frame.bitrate_switch);
  EXPECT_EQ(r.frame.length, 8);
  r = parse_ok("(1795248289.903181) vcan0 043##4");
  EXPECT_TRUE(r.frame.fd);
  EXPECT_FALSE(r.frame.bitrate_switch);
  EXPECT_EQ(r.frame.length, 0);
  r = parse_ok("(1795248289.952430) vcan0 123#R");
  EXPECT_TRUE(r.remote_request);
  r = parse_ok("(1.5) can1 1ABCDEF0#");
  EXPECT_TRUE(r.frame.extended);
  EXPECT_EQ(r.frame.length, 0);
  EXPECT_EQ(r.timestamp->count(), 1'500'000'000);
  r = parse_ok("(0.000001) can0 20000004#0004000000000000");  // error frame (controller problem)
  EXPECT_TRUE(r.frame.error);
  EXPECT_EQ(r.frame.id, 0x4U);
  r = parse_ok("(0.000001) can0 123#11.22.33");  // cansend-style separators
  EXPECT_EQ(r.frame.length, 3);
  r = parse_ok("(0.000001) can0 123#1122334455667788_C");  // len8_dlc suffix
  EXPECT_EQ(r.frame.length, 8);
}

TEST(protocol_candump, ExtraColumns) {
  Record r = parse_ok(" (1795248289.886426)  vcan0  TX B -       123  [08]  DE AD BE EF 00 11 22 33");
  EXPECT_TRUE(r.frame.fd);
  EXPECT_TRUE(r.frame.bitrate_switch);
  r = parse_ok("  vcan0  12345678   [8]  00 11 22 33 44 55 66 77   '..\"3DUfw'");
  EXPECT_EQ(r.frame.length, 8);
  r = parse_ok("  vcan0       043  [00]                            ''");
  EXPECT_EQ(r.frame.length, 0);
  r = parse_ok("  can0  20000080   [8]  00 00 00 00 00 00 00 00   ERRORFRAME");
  EXPECT_TRUE(r.frame.error);
  r = parse_ok("  vcan0       123   [0]  remote request");
  EXPECT_TRUE(r.remote_request);
}

TEST(protocol_candump, MalformedLinesAreErrors) {
  for (const char* line : {
           "",
           "   ",
           "garbage",
           "vcan0",
           "(123.456 vcan0 123#00",
           "(abc) vcan0 123#00",
           "(1.2) vcan0 12#00",
           "(1.2) vcan0 1234#00",
           "(1.2) vcan0 800#00",
           "(1.2) vcan0 123#0",
           "(1.2) vcan0 123#0G",
           "(1.2) vcan0 123#001122334455667788",
           "(1.2) vcan0 123##",
           "(1.2) vcan0 123##1001122334455667788",  // 9 bytes is no CAN FD length
           "(1.2) vcan0 123#R9",
           "(1.2) vcan0 123#00 trailing junk",
           "(1.2) vcan0 4FFFFFFF#00",
           "  vcan0  123   [4]  DE AD BE",
           "  vcan0  123   [4]  DE AD BE XX",
           "  vcan0  123   [9]  00 00 00 00 00 00 00 00 00",
           "  vcan0  123  [09]  00 00 00 00 00 00 00 00 00",
           "  vcan0  123   4  DE AD BE EF",
           "  vcan0  123   [4]  DE AD BE EF junk",
           "  vcan0  TX X -  123   [4]  DE AD BE EF",
           " (2026-13-21 08:04:49.854339)  vcan0  123   [4]  DE AD BE EF",
           " (2026-11-21 08:04:49.1234567890)  vcan0  123   [4]  DE AD BE EF",
           // Beyond 64-bit nanoseconds since the epoch (found by tests/fuzz/fuzz_candump:
           // the conversion overflowed, undefined behaviour), and before candump's epoch.
           " (9999-12-31 23:59:59.000000)  vcan0  123   [4]  DE AD BE EF",
           " (2263-01-01 00:00:00.000000)  vcan0  123   [4]  DE AD BE EF",
           " (0001-01-01 00:00:00.000000)  vcan0  123   [4]  DE AD BE EF",
           "  vcan0  1ABCDEF0  [00]  remote request",  // CAN FD has no remote frames (fuzz_candump)
       }) {
    const ParseResult r = parse_line(line);
    EXPECT_FALSE(r.ok()) << "accepted '" << line << "'";
    EXPECT_FALSE(r.error.empty()) << line;
  }
}

TEST(protocol_candump, LogLineRoundTrip) {
  for (const char* line : {"(1795248289.854339) vcan0 123#DEADBEEF", "(0.000000) can1 1ABCDEF0#00",
                           "(12.000100) vcan0 020##1000102030405060708090A0B", "(5.000000) vcan0 7FF#",
                           "(5.000000) vcan0 123#R"}) {
    EXPECT_EQ(to_log_line(parse_ok(line)), line);
  }
}

// ---------------------------------------------------------------------------------------
// Real candump output, all formats, from tests/unit/data/candump (see its README)
// ---------------------------------------------------------------------------------------

TEST(protocol_candump, RealOutputsOfAllFormatsAgree) {
  const std::vector<Record> reference = [] {
    std::vector<Record> out;
    for (const std::string& line : read_lines(kDataDir + "formats_L.log")) {
      out.push_back(parse_ok(line));
    }
    return out;
  }();
  ASSERT_EQ(reference.size(), 10U);
  for (const char* name : {"default", "a", "ta", "tz", "tA", "x"}) {
    const std::vector<std::string> lines = read_lines(kDataDir + "formats_" + name + ".log");
    ASSERT_EQ(lines.size(), reference.size()) << name;
    for (std::size_t i = 0; i < lines.size(); ++i) {
      const Record r = parse_ok(lines[i]);
      const CanFrame& a = r.frame;
      const CanFrame& b = reference[i].frame;
      EXPECT_EQ(a.id, b.id) << name << ":" << i;
      EXPECT_EQ(a.extended, b.extended) << name << ":" << i;
      EXPECT_EQ(a.fd, b.fd) << name << ":" << i;
      EXPECT_EQ(a.length, b.length) << name << ":" << i;
      EXPECT_TRUE(std::equal(a.data.begin(), a.data.begin() + a.length, b.data.begin())) << name << ":" << i;
      EXPECT_EQ(r.remote_request, reference[i].remote_request) << name << ":" << i;
      if (std::string_view(name) == "ta" || std::string_view(name) == "x" || std::string_view(name) == "tA") {
        EXPECT_EQ(r.timestamp, reference[i].timestamp) << name << ":" << i;
      }
      if (std::string_view(name) == "x") {
        EXPECT_EQ(a.bitrate_switch, b.bitrate_switch) << i;
      }
    }
  }
  // What was sent (cansend arguments, see the README).
  EXPECT_TRUE(reference[2].frame.fd && reference[2].frame.bitrate_switch);
  EXPECT_EQ(reference[7].frame.length, 24);
  EXPECT_EQ(reference[8].frame.length, 64);
  EXPECT_TRUE(reference[8].frame.extended);
  EXPECT_EQ(reference[9].frame.length, 12);
  EXPECT_EQ(to_log_line(reference[0]), read_lines(kDataDir + "formats_L.log")[0]);
}

// ---------------------------------------------------------------------------------------
// Decoding with the DBC, cantools style
// ---------------------------------------------------------------------------------------

TEST(protocol_candump, DecodeLineLikeCantools) {
  const dbc::Database db = dbc::parse(protocol::generate_dbc(0));
  protocol::ThermalEstimate t;
  t.valid = true;
  t.winding_temp_C = 87.25;
  t.winding_temp_sigma_C = 1.5;
  t.calibrated = true;
  CanFrame f;
  ASSERT_EQ(protocol::encode(t, 0, f), protocol::EncodeStatus::kOk);
  Record rec;
  rec.format = Format::kLog;
  rec.timestamp = nanoseconds(1'000'000'000);
  rec.interface = "vcan0";
  rec.frame = f;
  const std::string line = to_log_line(rec);
  EXPECT_EQ(line, "(1.000000) vcan0 110#1522960000000300");
  const DecodedLine d = decode_line(db, line);
  EXPECT_TRUE(d.parsed);
  EXPECT_TRUE(d.known);
  EXPECT_EQ(d.text,
            "(1.000000) vcan0 110#1522960000000300 :: THERMAL_ESTIMATE(WindingTemp: 87.25 degC, WindingTempSigma: "
            "1.50 degC, MagnetTemp: 0.00 degC, Valid: 1, Calibrated: 1, DeratingActive: 0, Stale: 0, MagnetValid: 0, CalibrationResult: NONE, Calibrating: 0, MagnetTempSigma: 0.00 degC)");

  protocol::DriveCommand c;
  c.enable = true;
  c.mode = protocol::DriveMode::kSpeed;
  c.speed_setpoint_rad_s = -314.159;
  ASSERT_EQ(protocol::encode(c, 0, 3, f), protocol::EncodeStatus::kOk);
  rec.frame = f;
  const DecodedLine cmd = decode_line(db, to_log_line(rec));
  EXPECT_NE(cmd.text.find(":: DRIVE_COMMAND("), std::string::npos) << cmd.text;
  EXPECT_NE(cmd.text.find("AliveCounter: 3, Enable: 1, Mode: SPEED, SpeedSetpoint: -314.159 rad/s, "
                          "TorqueSetpoint: 0.000 Nm)"),
            std::string::npos)
      << cmd.text;

  EXPECT_EQ(decode_line(db, "  vcan0  7E0   [1]  00").text, "  vcan0  7E0   [1]  00 :: Unknown frame id 2016 (0x7e0)");
  const DecodedLine junk = decode_line(db, "not a frame\n");
  EXPECT_FALSE(junk.parsed);
  EXPECT_EQ(junk.text, "not a frame");
}

// Frames of every message, encoded by the codec, sent with cansend and captured with real
// candump (-L and default) inside UML: the committed DBC and the codec both decode them.
TEST(protocol_candump, RealCaptureOfProtocolFramesDecodes) {
  const dbc::Database db = dbc::load(std::string(PMSM_SOURCE_DIR) + "/can/pmsm-thermal.dbc");
  const std::vector<std::string> log = read_lines(kDataDir + "protocol_node0.log");
  const std::vector<std::string> plain = read_lines(kDataDir + "protocol_node0_default.log");
  ASSERT_EQ(log.size(), 17U);
  ASSERT_EQ(plain.size(), log.size());
  std::set<std::string> seen;
  protocol::DaemonReceiver daemon(0);
  for (std::size_t i = 0; i < log.size(); ++i) {
    const DecodedLine a = decode_line(db, log[i]);
    const DecodedLine b = decode_line(db, plain[i]);
    ASSERT_TRUE(a.parsed && a.known) << a.text;
    ASSERT_TRUE(b.parsed && b.known) << b.text;
    // Same decoding from both formats.
    EXPECT_EQ(a.text.substr(a.text.find(" :: ")), b.text.substr(b.text.find(" :: "))) << i;
    EXPECT_EQ(a.text.find("mismatch"), std::string::npos) << a.text;
    const CanFrame frame = parse_ok(log[i]).frame;
    protocol::AnyDecoded any;
    ASSERT_EQ(protocol::decode_any(frame, any), protocol::DecodeStatus::kOk) << log[i];
    seen.insert(std::string(protocol::message_def(any.type).name));
    if (protocol::message_def(any.type).received_by(protocol::Role::kDaemon)) {
      EXPECT_FALSE(std::holds_alternative<protocol::Rejected>(daemon.receive(frame, nanoseconds{0}))) << log[i];
    }
  }
  EXPECT_EQ(seen.size(), protocol::kMessageCount);
  EXPECT_EQ(daemon.counters().accepted(), 4U);

  const std::string thermal = decode_line(db, log[7]).text;
  EXPECT_EQ(thermal.substr(thermal.find(" :: ")),
            " :: THERMAL_ESTIMATE(WindingTemp: 87.25 degC, WindingTempSigma: 1.50 degC, MagnetTemp: 61.20 degC, "
            "Valid: 1, Calibrated: 1, DeratingActive: 1, Stale: 0, MagnetValid: 1, CalibrationResult: NONE, Calibrating: 0, MagnetTempSigma: 0.00 degC)");
  const std::string drive = decode_line(db, log[2]).text;
  EXPECT_NE(drive.find("Mode: SPEED, SpeedSetpoint: 157.080 rad/s"), std::string::npos) << drive;
  const std::string sample = decode_line(db, plain[1]).text;
  EXPECT_NE(sample.find("SENSOR_SAMPLE(Sequence: 1001, PhaseCurrentAdcA: 205, PhaseCurrentAdcB: -102"),
            std::string::npos)
      << sample;
  const std::string invalid = decode_line(db, log[16]).text;
  EXPECT_NE(invalid.find("Valid: 0"), std::string::npos) << invalid;
}

// Random printable junk never crashes the line parser.
TEST(protocol_fuzz, RandomCandumpLines) {
  std::mt19937_64 rng(99);
  const std::string alphabet = "0123456789ABCDEFabcdef#.()[] -_'RTXBEvcan";
  std::uniform_int_distribution<std::size_t> pick(0, alphabet.size() - 1);
  std::uniform_int_distribution<int> length(0, 120);
  int ok = 0;
  for (int i = 0; i < 50000; ++i) {
    std::string line;
    if (i % 3 == 0) {
      line = "(1.000000) vcan0 ";
    }
    const int n = length(rng);
    for (int k = 0; k < n; ++k) {
      line.push_back(alphabet[pick(rng)]);
    }
    const ParseResult r = parse_line(line);
    if (r.ok()) {
      ++ok;
      EXPECT_LE(r.record->frame.length, CanFrame::kMaxFdLength);
    } else {
      EXPECT_FALSE(r.error.empty());
    }
  }
  SUCCEED() << ok << " random lines parsed";
}

}  // namespace
}  // namespace pmsm::hal::candump

namespace pmsm::hal::candump {
namespace {

// An error quotes the bad piece with its control characters escaped (a log's terminal escapes
// went raw to the reader's terminal through decode's message) and at most 64 characters long.
TEST(protocol_candump, AnErrorQuotesThePieceEscapedAndShort) {
  const ParseResult escape = parse_line("(1.0) vcan0 123#11\x1b]0;title\x07");
  ASSERT_FALSE(escape.ok());
  EXPECT_NE(escape.error.find("'123#11\\x1b]0;title\\x07'"), std::string::npos) << escape.error;
  EXPECT_EQ(escape.error.find('\x1b'), std::string::npos);
  // A timestamp's and an interface's too; an interface the kernel could not have named (a
  // control character, 16 characters) is no candump line: decode printed it back raw.
  for (const std::string& line : {std::string("(17\x1b[31m0.0) vcan0 123#11"), std::string("(1.0) vcan0\x1b[31m 123#11"),
                                 std::string("(1.0) vc\x1b]0;t\x07an0 123#11"), std::string("vcan0\x1b[2J 123 [1] 11")}) {
    const ParseResult refused = parse_line(line);
    ASSERT_FALSE(refused.ok()) << refused.error;
    EXPECT_NE(refused.error.find("\\x1b"), std::string::npos) << refused.error;
    EXPECT_EQ(refused.error.find('\x1b'), std::string::npos) << refused.error;
  }
  EXPECT_NE(parse_line("(1.0) vcan0123456789ab 123#11").error.find("bad interface: an interface name is 1 to 15 characters, got 16"),
            std::string::npos);
  EXPECT_TRUE(parse_line("(1.0) can-axis_1.a 123#11").ok()) << "any name the daemon takes";
  const ParseResult longer = parse_line("(1.0) vcan0 123#" + std::string(1000, 'Z'));
  ASSERT_FALSE(longer.ok());
  EXPECT_LT(longer.error.size(), 120U) << longer.error;
  EXPECT_NE(longer.error.find("...'"), std::string::npos) << longer.error;
}

}  // namespace
}  // namespace pmsm::hal::candump
