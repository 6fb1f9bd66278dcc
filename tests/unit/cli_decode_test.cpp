// `pmsm-thermal decode` on the committed candump captures (tests/unit/data/candump/): every
// candump format, stdin, --json, --strict, the default DBC lookup, and errors that name the
// DBC file and line.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "run_process.hpp"

namespace pmsm::test {
namespace {

const std::string kExe = PMSM_THERMAL_EXE;
const std::string kSource = PMSM_SOURCE_DIR;
const std::string kData = kSource + "/tests/unit/data/candump/";
const std::string kDbc = kSource + "/can/pmsm-thermal.dbc";
const std::string kDecode = kExe + " decode --dbc " + kDbc + " ";

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    lines.push_back(line);
  }
  return lines;
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// What follows " :: " on each line.
std::vector<std::string> decoded_parts(const std::string& out) {
  std::vector<std::string> parts;
  for (const std::string& line : lines_of(out)) {
    const std::size_t at = line.find(" :: ");
    parts.push_back(at == std::string::npos ? std::string{} : line.substr(at + 4));
  }
  return parts;
}

class TempFile {
 public:
  explicit TempFile(const std::string& text, const char* suffix = ".log") {
    std::string name = std::string("/tmp/cli-decode-XXXXXX") + suffix;
    const int fd = ::mkstemps(name.data(), static_cast<int>(std::string(suffix).size()));
    if (fd >= 0) {
      ::close(fd);
    }
    path_ = name;
    std::ofstream(path_) << text;
  }
  ~TempFile() { std::remove(path_.c_str()); }
  TempFile(const TempFile&) = delete;
  TempFile& operator=(const TempFile&) = delete;
  [[nodiscard]] const std::string& path() const { return path_; }

 private:
  std::string path_;
};

TEST(cli_decode, EveryProtocolMessageDecodesWithLabels) {
  const ProcessResult r = run_process(kDecode + "--strict " + kData + "protocol_node0.log");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> input = lines_of(read_file(kData + "protocol_node0.log"));
  const std::vector<std::string> output = lines_of(r.out);
  ASSERT_EQ(output.size(), input.size());
  for (std::size_t i = 0; i < input.size(); ++i) {
    // The original line, then the decoded message.
    EXPECT_EQ(output[i].rfind(input[i] + " :: ", 0), 0U) << output[i];
  }
  EXPECT_TRUE(contains(r.out, ":: INVERTER_COMMAND(Sequence: 1000, DutyA: 0.500008,")) << r.out;
  EXPECT_TRUE(contains(r.out, ":: DRIVE_COMMAND(Crc: 123, AliveCounter: 0, Enable: 1, Mode: SPEED, "
                              "SpeedSetpoint: 157.080 rad/s, TorqueSetpoint: 0.000 Nm)"))
      << r.out;
  EXPECT_TRUE(contains(r.out, ":: PLANT_STATUS(Mode: LOCKSTEP, OutputEnabled: 1,")) << r.out;
  EXPECT_TRUE(contains(r.out, "Result: ACCEPTED")) << r.out;
  // Summary on stderr: all decoded, counts per message.
  EXPECT_TRUE(contains(r.err, "17 frame(s): 17 decoded, 0 unknown")) << r.err;
  EXPECT_TRUE(std::regex_search(r.err, std::regex("THERMAL_ESTIMATE +2\\n"))) << r.err;
  EXPECT_TRUE(std::regex_search(r.err, std::regex("PLANT_STATUS +1\\n"))) << r.err;
}

TEST(cli_decode, DefaultAndLogFormatsDecodeAlike) {
  const ProcessResult log = run_process(kDecode + kData + "protocol_node0.log");
  const ProcessResult plain = run_process(kDecode + kData + "protocol_node0_default.log");
  ASSERT_EQ(log.exit_code, 0) << log.err;
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  EXPECT_EQ(decoded_parts(log.out), decoded_parts(plain.out));
}

TEST(cli_decode, EveryCandumpFormatGivesTheSameResult) {
  const ProcessResult reference = run_process(kDecode + kData + "formats_L.log");
  ASSERT_EQ(reference.exit_code, 0) << reference.err;
  const std::vector<std::string> expected = decoded_parts(reference.out);
  ASSERT_EQ(expected.size(), 10U);
  for (const char* name : {"formats_default.log", "formats_a.log", "formats_ta.log", "formats_tz.log",
                           "formats_tA.log", "formats_x.log"}) {
    const ProcessResult r = run_process(kDecode + kData + name);
    ASSERT_EQ(r.exit_code, 0) << name << ": " << r.err;
    EXPECT_EQ(decoded_parts(r.out), expected) << name;
    EXPECT_TRUE(contains(r.err, "10 frame(s): 2 decoded, 7 unknown, 0 error frame(s), 0 mismatched")) << name << r.err;
  }
  EXPECT_TRUE(contains(reference.out, "vcan0 12345678#0011223344556677 :: Unknown frame id")) << reference.out;
  EXPECT_TRUE(contains(reference.out, ":: SENSOR_SAMPLE(Sequence: 50462976,")) << reference.out;
}

TEST(cli_decode, StrictFailsOnUnknownFrames) {
  const ProcessResult r = run_process(kDecode + "--strict " + kData + "formats_L.log");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.err, "--strict: 8 line(s)")) << r.err;  // 7 unknown + 1 out of range
  // Everything is still printed.
  EXPECT_EQ(lines_of(r.out).size(), 10U);
}

TEST(cli_decode, StrictFailsOnMismatchOutOfRangeAndMalformedLines) {
  // PLANT_STATUS one byte short; DRIVE_STATUS with State 7 (range 0..4); a line that is no frame.
  const TempFile bad("(1.000000) vcan0 220#03000001007F7E\n(1.000100) vcan0 100#0700000000000000\nhello\n\n");
  const ProcessResult r = run_process(kDecode + "--strict " + bad.path());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_TRUE(contains(r.out, ":: PLANT_STATUS(")) << r.out;
  EXPECT_TRUE(contains(r.out, "[length mismatch]")) << r.out;
  EXPECT_TRUE(contains(r.out, "[out of range: State]")) << r.out;
  EXPECT_TRUE(contains(r.err, "line 3 is not a candump frame")) << r.err;
  EXPECT_TRUE(contains(r.err, "1 mismatched")) << r.err;
  EXPECT_TRUE(contains(r.err, "1 out of range, 0 with a bad CRC, 0 with a bad alive counter, 1 malformed line(s)")) << r.err;
  // Without --strict the same input is reported but does not fail.
  EXPECT_EQ(run_process(kDecode + bad.path()).exit_code, 0);
}

// A log's terminal escapes do not reach the reader's terminal: a line that is no frame is passed
// through with its control characters as \xNN, and an interface name with one is no frame (the
// kernel's names have none); its message quotes it escaped. Before, both went out raw.
TEST(cli_decode, ControlCharactersInALogAreShownEscaped) {
  const TempFile log("(1.000000) vcan0\x1b[31m 100#0200000000000000\nhello\x1b]0;title\x07\n(1.000100) vcan0 100#0200000000000000\n");
  const ProcessResult r = run_process(kDecode + log.path());
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out.find('\x1b'), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find('\x1b'), std::string::npos) << r.err;
  EXPECT_TRUE(contains(r.out, "(1.000000) vcan0\\x1b[31m 100#0200000000000000\nhello\\x1b]0;title\\x07\n")) << r.out;
  EXPECT_TRUE(contains(r.err, "line 1 is not a candump frame: bad interface: an interface name has no control characters "
                              "(a NUL would end it early), got 'vcan0\\x1b[31m'")) << r.err;
  EXPECT_TRUE(contains(r.out, ":: DRIVE_STATUS(")) << r.out;
  EXPECT_TRUE(contains(r.err, "1 decoded")) << r.err;
  // A line that parses carries them too: candump -a's ASCII column, a carriage return inside
  // the line, an unknown frame's, and an 8-bit CSI (0x9b).
  const TempFile parsed("(1.000000) vcan0 100#0200000000000000\r\n"
                        "  vcan0  100   [8]  02 00 00 00 00 00 00 00   '.\x1b]0;t\x07.'\n"
                        "(1.000100) vcan0\r7FF#11\n"
                        "(1.000200) vcan0 100#0200000000000000\n\x9b" "2J\n");
  const ProcessResult p = run_process(kDecode + parsed.path());
  EXPECT_EQ(p.out.find('\x1b'), std::string::npos) << p.out;
  EXPECT_EQ(p.out.find('\x07'), std::string::npos) << p.out;
  EXPECT_EQ(p.out.find('\r'), std::string::npos) << p.out;
  EXPECT_EQ(p.out.find('\x9b'), std::string::npos) << p.out;
  EXPECT_TRUE(contains(p.out, "\\x9b2J")) << p.out;
}

// A line without an end (a binary file, a capture cut mid-write) is read up to 4096 characters
// and the rest of it skipped, not into memory whole: named, counted, and the frames around it
// decoded. (Before, decode read a line of any length: /dev/zero grew it by gigabytes a second
// until std::bad_alloc aborted it.)
TEST(cli_decode, AnOverlongLineIsCutNamedAndSkipped) {
  const std::string frame = "(1.000100) vcan0 100#0200000000000000\n";
  const TempFile log(frame + std::string(1'000'000, 'A') + "\n" + frame + std::string(5000, '7'));
  const ProcessResult r = run_process(kDecode + log.path());
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_TRUE(contains(r.err, "line 2 is not a candump frame: longer than 4096 characters (the rest of it skipped)"))
      << r.err;
  EXPECT_TRUE(contains(r.err, "line 4 is not a candump frame: longer than 4096")) << r.err;
  EXPECT_TRUE(contains(r.err, "2 malformed line(s)")) << r.err;
  std::size_t frames = 0;
  for (const std::string& line : lines_of(r.out)) {
    frames += contains(line, ":: DRIVE_STATUS(") ? 1U : 0U;
    EXPECT_LE(line.size(), 4096U) << "a line echoed longer than it was read";
  }
  EXPECT_EQ(frames, 2U) << "the frames before and after";
}

// An input without a single frame is no capture (a binary file, the wrong file): exit 2, with or
// without --strict (before, without it, 0 with every line counted as malformed).
TEST(cli_decode, AnInputWithoutAFrameIsNoCapture) {
  const TempFile junk("\x7f" "ELF\x02\x01\x01 binary\nnot a frame either\n");
  const ProcessResult r = run_process(kDecode + junk.path());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "decode: no line of '" + junk.path() + "' is a candump frame: not a capture")) << r.err;
  const TempFile empty("");
  EXPECT_EQ(run_process(kDecode + empty.path()).exit_code, 0) << "an empty capture is a capture of nothing";
}

TEST(cli_decode, ACommandWithABadCrcIsReportedAsCorrupt) {
  // The DRIVE_COMMAND of protocol_node0.log (CRC 0x7B), once as sent and once with its CRC
  // byte changed: a DBC tool decodes both alike; the codec knows the second is corrupt.
  const TempFile log("(1.000000) vcan0 040#7B50986502000000\n(1.000100) vcan0 040#7C50986502000000\n");
  const ProcessResult r = run_process(kDecode + "--strict " + log.path());
  EXPECT_EQ(r.exit_code, 1);
  const std::vector<std::string> out = lines_of(r.out);
  ASSERT_EQ(out.size(), 2U) << r.out;
  EXPECT_FALSE(contains(out[0], "CRC-8")) << out[0];
  EXPECT_TRUE(contains(out[1], "CRC-8 does not match")) << out[1];
  EXPECT_TRUE(contains(r.err, "1 with a bad CRC")) << r.err;
}

TEST(cli_decode, AReplayedCommandIsReportedByItsAliveCounter) {
  // The same DRIVE_COMMAND twice (a replay: the counter does not advance), then one whose
  // counter advanced properly is taken again.
  const TempFile log("(1.000000) vcan0 040#7B50986502000000\n(1.000100) vcan0 040#7B50986502000000\n");
  const ProcessResult r = run_process(kDecode + "--strict " + log.path());
  EXPECT_EQ(r.exit_code, 1);
  const std::vector<std::string> out = lines_of(r.out);
  ASSERT_EQ(out.size(), 2U) << r.out;
  EXPECT_FALSE(contains(out[0], "AliveCounter (")) << out[0];
  EXPECT_TRUE(contains(out[1], "AliveCounter (repeated_counter")) << out[1];
  EXPECT_TRUE(contains(r.err, "1 with a bad alive counter")) << r.err;
}

// A command whose CRC holds but whose value is out of range is genuine: as in the daemon
// (docs/protocol.md: the counter is checked before the ranges), it advances its stream. Node 1's
// CALIBRATION_COMMAND with counters 0-5, four of them out of range (a hostile-bus probe's
// frames): the last one follows its predecessor. Before, decode and monitor flagged it as a
// counter jump the daemon had not seen.
TEST(cli_decode, AnOutOfRangeCommandAdvancesItsAliveCounter) {
  const TempFile dbc("", ".dbc");
  ASSERT_EQ(run_process(kExe + " dbc --node 1 -o " + dbc.path()).exit_code, 0);
  const TempFile log(
      "(1.000000) vcan0 061#B500C40900000000\n(1.050000) vcan0 061#3E31C40900000000\n"
      "(1.100000) vcan0 061#9B12FF7F00000000\n(1.150000) vcan0 061#2013008000000000\n"
      "(1.200000) vcan0 061#F914993A00000000\n(1.250000) vcan0 061#EE25C40900000000\n");
  const ProcessResult r = run_process(kExe + " decode --dbc " + dbc.path() + " " + log.path());
  const std::vector<std::string> out = lines_of(r.out);
  ASSERT_EQ(out.size(), 6U) << r.out;
  EXPECT_TRUE(contains(out[4], "out of range: KnownTemp")) << out[4];
  EXPECT_FALSE(contains(out[5], "AliveCounter (")) << out[5];
  EXPECT_TRUE(contains(r.err, "4 out of range, 0 with a bad CRC, 0 with a bad alive counter")) << r.err;
}

TEST(cli_decode, ReadsStdin) {
  const ProcessResult dash = run_process("cat " + kData + "protocol_node0.log | " + kDecode + "-");
  const ProcessResult none = run_process("cat " + kData + "protocol_node0.log | " + kDecode);
  const ProcessResult file = run_process(kDecode + kData + "protocol_node0.log");
  ASSERT_EQ(dash.exit_code, 0) << dash.err;
  ASSERT_EQ(none.exit_code, 0) << none.err;
  EXPECT_EQ(dash.out, file.out);
  EXPECT_EQ(none.out, file.out);
}

TEST(cli_decode, JsonLinesOnePerFrame) {
  const ProcessResult r = run_process(kDecode + "--json " + kData + "protocol_node0.log");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> lines = lines_of(r.out);
  ASSERT_EQ(lines.size(), 17U);
  for (const std::string& line : lines) {
    EXPECT_EQ(line.front(), '{');
    EXPECT_EQ(line.back(), '}');
    EXPECT_TRUE(contains(line, "\"status\": \"ok\"")) << line;
  }
  EXPECT_TRUE(contains(lines[0], "\"timestamp_ns\": 1795493852250683000")) << lines[0];
  EXPECT_TRUE(contains(lines[0], "\"message\": \"INVERTER_COMMAND\"")) << lines[0];
  EXPECT_TRUE(contains(lines[0], "\"Sequence\": 1000")) << lines[0];
  EXPECT_TRUE(contains(r.out, "\"labels\": {\"Mode\": \"SPEED\"}")) << r.out;
  EXPECT_TRUE(contains(r.out, "\"units\": {\"SpeedSetpoint\": \"rad/s\", \"TorqueSetpoint\": \"Nm\"}")) << r.out;
  // The summary is one JSON object on stderr.
  EXPECT_TRUE(contains(r.err, "\"frames\": 17, \"decoded\": 17")) << r.err;
  EXPECT_TRUE(contains(r.err, "\"THERMAL_ESTIMATE\": 2")) << r.err;
}

// A line's bytes that are no UTF-8 are written as U+FFFD: the output stays JSON whatever the
// capture holds; well-formed UTF-8 passes as it is.
TEST(cli_decode, JsonStaysJsonWhateverTheLineHolds) {
  const TempFile log("(1.000000) vcan0 \xff\xfe caf\xc3\xa9 \xed\xa0\x80 \xe2\x82\n");
  const ProcessResult r = run_process(kDecode + "--json " + log.path());
  const std::vector<std::string> lines = lines_of(r.out);
  ASSERT_EQ(lines.size(), 1U) << r.out;
  EXPECT_TRUE(contains(lines[0], "\\ufffd\\ufffd caf\xc3\xa9 \\ufffd\\ufffd\\ufffd \\ufffd\\ufffd")) << lines[0];
  for (const char c : lines[0]) {
    const auto b = static_cast<unsigned char>(c);
    EXPECT_TRUE(b < 0x80 || b == 0xc3 || b == 0xa9) << "a raw byte " << static_cast<int>(b) << " in " << lines[0];
  }
}

TEST(cli_decode, FindsTheDbcWithoutBeingTold) {
  // The executable lives in a build directory under the source tree: can/pmsm-thermal.dbc
  // of that tree is found.
  const ProcessResult r = run_process(kExe + " decode --strict " + kData + "protocol_node0.log");
  if (kExe.rfind(kSource + "/", 0) != 0) {
    GTEST_SKIP() << "the build directory is outside the source tree";
  }
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(contains(r.err, "17 decoded")) << r.err;
}

TEST(cli_decode, AnUnreadableDbcIsNamedWithItsLine) {
  const TempFile bad("VERSION \"\"\nBU_: A\nBO_ 12 X: 8 A\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" A\nBO_ nonsense\n", ".dbc");
  ProcessResult r = run_process(kExe + " decode --dbc " + bad.path() + " " + kData + "protocol_node0.log");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, bad.path() + ":5:")) << r.err;
  r = run_process(kExe + " decode --dbc /nonexistent/x.dbc " + kData + "protocol_node0.log");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "/nonexistent/x.dbc")) << r.err;
  // A directory opens as a stream and an empty file parses: both decoded nothing, exit 0.
  r = run_process(kExe + " decode --dbc /tmp " + kData + "protocol_node0.log");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "decode: cannot read the DBC: /tmp: is a directory")) << r.err;
  const TempFile empty("", ".dbc");
  r = run_process(kExe + " decode --dbc " + empty.path() + " " + kData + "protocol_node0.log");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "decode: the DBC " + empty.path() + " defines no messages (no BO_ line)")) << r.err;
}

// Another axis's frames with the node-0 DBC: unknown, and the summary says whose they are.
TEST(cli_decode, AnotherNodesFramesAreNamedInTheSummary) {
  const TempFile log("(1.000000) vcan0 141#0000000000000000\n(1.100000) vcan0 111#0000000000000000\n"
                     "(1.200000) vcan0 140#0000000000000000\n(1.300000) vcan0 7F3#00\n");
  const ProcessResult r = run_process(kDecode + log.path());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(contains(r.err, "1 decoded, 3 unknown")) << r.err;
  EXPECT_TRUE(contains(r.err, "2 unknown frame(s) are this DBC's messages for node 1")) << r.err;
  EXPECT_TRUE(contains(r.err, "`pmsm-thermal dbc --node 1 -o node1.dbc`")) << r.err;
  EXPECT_FALSE(contains(r.err, "for node 3")) << "0x7F3 is no message's base: " << r.err;
  // What the summary says to run gives the DBC that decodes them.
  const TempFile node1("", ".dbc");
  const ProcessResult made = run_process(kExe + " dbc --node 1 -o " + node1.path());
  ASSERT_EQ(made.exit_code, 0) << made.err;
  const ProcessResult again = run_process(kExe + " decode --dbc " + node1.path() + " " + log.path());
  EXPECT_EQ(again.exit_code, 0) << again.err;
  EXPECT_TRUE(contains(again.err, "2 decoded, 2 unknown")) << again.err;
}

// `pmsm-thermal dbc`: node 0's is the committed (and packaged) file byte for byte, on standard
// output or written over an existing file; another node's has the same messages and signals and
// says which node it is; a node outside 0..15 is a bad command line (2); a directory, an
// unwritable path and a full standard output are named with their reason (3, as simulate's
// outputs).
TEST(cli_dbc, GivesEachNodesDbc) {
  const std::string committed = read_file(kDbc);
  ProcessResult r = run_process(kExe + " dbc");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, committed);
  const TempFile written("stale contents", ".dbc");
  r = run_process(kExe + " dbc --node 0 --output " + written.path());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(read_file(written.path()), committed);
  r = run_process(kExe + " dbc --node 15");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out, committed);
  const auto count = [](const std::string& text, const std::string& what) {
    std::size_t n = 0;
    for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
    return n;
  };
  EXPECT_EQ(count(r.out, "\nBO_ "), count(committed, "\nBO_ ")) << "the same messages, other IDs";
  EXPECT_EQ(count(r.out, "\n SG_ "), count(committed, "\n SG_ ")) << "the same signals";
  EXPECT_GT(count(committed, "\nBO_ "), 10U);
  EXPECT_TRUE(contains(r.out, "\nBA_ \"ProtocolNodeId\" 15;")) << "node 15's DBC says so";
  EXPECT_TRUE(contains(committed, "\nBA_ \"ProtocolNodeId\" 0;"));
  r = run_process(kExe + " dbc --node 16");
  EXPECT_EQ(r.exit_code, 2) << "a bad command line";
  EXPECT_TRUE(contains(r.err, "--node")) << r.err;
  r = run_process(kExe + " dbc -o /tmp");
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_TRUE(contains(r.err, "dbc: '/tmp' is a directory")) << r.err;
  r = run_process(kExe + " dbc -o /nonexistent/axis2.dbc");
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_TRUE(contains(r.err, "dbc: cannot create '/nonexistent/axis2.dbc' (No such file or directory)")) << r.err;
  r = run_process(kExe + " dbc > /dev/full");
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_TRUE(contains(r.err, "dbc: cannot write standard output (No space left on device)")) << r.err;
}

// Output that did not reach standard output or its file (a full disk) is no success: 3, as for
// simulate's outputs and dbc's file, named on standard error; a check that failed keeps its 1.
TEST(cli_decode, AnOutputThatCouldNotBeWrittenFails) {
  const std::string commands[] = {"config-keys", "budget --speed 10", "budget --speed 10 --json", "losses --F 10",
                                   "decode --dbc " + kDbc + " " + kData + "protocol_node0.log",
                                   "--help", "--version", "simulate --help"};
  for (const std::string& args : commands) {
    const ProcessResult r = run_process(kExe + " " + args + " > /dev/full");
    EXPECT_EQ(r.exit_code, 3) << args << ": " << r.err;
    // (The reason where the failed write's is still known: a long output failed before the end.)
    EXPECT_TRUE(contains(r.err, "pmsm-thermal: cannot write standard output (")) << args << ": " << r.err;
    if (args.find("--help") != std::string::npos || args == "--version" || args == "config-keys") {
      // Written in one go: the reason is the failed write's own, not "a write failed" (a text
      // printed in pieces through the stream still says that: its errno is gone by the check).
      EXPECT_TRUE(contains(r.err, "(No space left on device)")) << args << ": " << r.err;
    }
  }
  const std::string monitor = kExe + " monitor --log " + kData + "protocol_node0.log --plain --csv ";
  ProcessResult r = run_process(monitor + "/dev/full > /dev/null");
  EXPECT_EQ(r.exit_code, 3) << r.err;
  EXPECT_TRUE(contains(r.err, "monitor: cannot write --csv '/dev/full' (")) << r.err;
  r = run_process(monitor + "/dev/null > /dev/null");
  EXPECT_EQ(r.exit_code, 0) << "the premise: the same run with room for its rows: " << r.err;
}

// The planning options take the configurations' floors (1e-300 V and 1e-300 V s/rad ran, and
// --pole-pairs took 100 where a configuration takes 64).
TEST(cli_decode, ThePlanningOptionsTakeTheConfigurationsFloors) {
  for (const std::string args : {"--vdc 1e-300", "--Ke 1e-300", "--pole-pairs 65"}) {
    const ProcessResult r = run_process(kExe + " budget --speed 100 " + args);
    EXPECT_EQ(r.exit_code, 2) << args << ": " << r.err;
    EXPECT_TRUE(contains(r.err, args.substr(0, args.find(' ')))) << args << ": " << r.err;
  }
}

TEST(cli_decode, AMissingInputFileIsNamed) {
  const ProcessResult r = run_process(kDecode + "/nonexistent/capture.log");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_TRUE(contains(r.err, "cannot open '/nonexistent/capture.log'")) << r.err;
}

// A directory reads as nothing: named as one, not decoded as an empty (clean) capture.
TEST(cli_decode, ADirectoryIsNoCapture) {
  const ProcessResult file = run_process(kDecode + "/tmp");
  EXPECT_EQ(file.exit_code, 2);
  EXPECT_TRUE(contains(file.err, "decode: '/tmp' is a directory, not a file")) << file.err;
  const ProcessResult piped = run_process(kDecode + "--strict - < /tmp");
  EXPECT_EQ(piped.exit_code, 2);
  EXPECT_TRUE(contains(piped.err, "decode: standard input is a directory, not a file")) << piped.err;
}

}  // namespace
}  // namespace pmsm::test
