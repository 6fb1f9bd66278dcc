// `pmsm-thermal decode`: candump output decoded through a DBC, as `cantools decode
// --single-line` prints it (cantools is not packaged for Debian 12). Reads the default, -a,
// -x, -ta/-tz/-td/-tA and -L formats, classic and CAN FD, from a file or stdin.
//
//   candump -L vcan0 | pmsm-thermal decode
//   pmsm-thermal decode --dbc can/pmsm-thermal.dbc --strict capture.log
//
// Each input line is printed, followed by " :: MESSAGE(Signal: value unit, ...)" for a frame
// the DBC knows (value-table labels instead of numbers), " :: Unknown frame id ..." for one
// it does not; other lines are printed unchanged. A summary with counts per message goes to
// stderr at the end. --json prints one JSON object per line instead (JSON Lines).
//
// Exit status: 0; 1 with --strict when any line was not a cleanly decoded frame (unknown
// ID, error frame, length or CAN FD/classic mismatch, signal outside its DBC range, or a
// non-empty line that is not a candump frame); 2 when the DBC or the input cannot be read
// (the message names the file and, for a DBC syntax error, the line), or when no line of the
// input is a candump frame (it is no capture). Without --strict,
// unknown frames are reported and counted but do not change the exit status, as with
// cantools: a bus usually carries traffic that one DBC does not describe.
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include <fmt/core.h>

#include "cli_validators.hpp"
#include "printable.hpp"
#include "json_writer.hpp"
#include "commands.hpp"
#include "text_input.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/tools/candump.hpp"
#include "pmsm/tools/dbc.hpp"

namespace pmsm::app {
namespace {

namespace fs = std::filesystem;
namespace dbc = hal::dbc;
namespace candump = hal::candump;

constexpr std::string_view kDbcName = "pmsm-thermal.dbc";
constexpr int kExitStrict = 1;
constexpr int kExitInput = 2;
constexpr int kMaxReportedBadLines = 10;

struct DecodeOptions {
  std::string dbc_path;
  std::string input = "-";
  bool json = false;
  bool strict = false;
  bool quiet = false;
};

// Where the DBC is looked for when --dbc is not given, in order: next to an installed
// executable (<prefix>/bin/pmsm-thermal -> <prefix>/share/pmsm-thermal/), the source tree
// holding a build directory (any parent of the executable with can/pmsm-thermal.dbc), and
// can/ under the working directory.
std::vector<fs::path> default_dbc_candidates() {
  std::vector<fs::path> candidates;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const fs::path bin_dir = exe.parent_path();
    candidates.push_back(bin_dir.parent_path() / "share" / "pmsm-thermal" / kDbcName);
    for (fs::path dir = bin_dir; !dir.empty(); dir = dir.parent_path()) {
      candidates.push_back(dir / "can" / kDbcName);
      if (dir == dir.root_path()) {
        break;
      }
    }
  }
  candidates.push_back(fs::current_path(ec) / "can" / kDbcName);
  return candidates;
}

std::optional<fs::path> find_default_dbc(std::string& looked_in) {
  for (const fs::path& candidate : default_dbc_candidates()) {
    std::error_code ec;
    if (fs::is_regular_file(candidate, ec)) {
      return candidate;
    }
    looked_in += (looked_in.empty() ? "" : ", ") + candidate.string();
  }
  return std::nullopt;
}

enum class LineKind : std::uint8_t { kBlank, kMalformed, kErrorFrame, kUnknown, kMismatch, kOutOfRange, kDecoded };

struct Counts {
  std::uint64_t lines = 0;
  std::uint64_t frames = 0;
  std::uint64_t decoded = 0;      // known, length and format as in the DBC, values in range
  std::uint64_t unknown = 0;
  std::uint64_t error_frames = 0;
  std::uint64_t malformed = 0;    // non-empty lines that are not candump frames
  std::uint64_t mismatched = 0;   // length or CAN FD/classic differs from the DBC
  std::uint64_t out_of_range = 0; // a signal outside the DBC's [minimum, maximum]
  std::uint64_t bad_crc = 0;      // a command frame whose CRC-8 does not match (corrupt)
  std::uint64_t bad_counter = 0;  // a command whose alive counter repeats or jumps (replayed, stale, lost)
  std::vector<std::uint64_t> per_message;  // indexed like Database::messages

  [[nodiscard]] std::uint64_t bad() const noexcept {
    return unknown + error_frames + malformed + mismatched + out_of_range + bad_crc + bad_counter;
  }
};

// Whether a decoded value lies outside the signal's declared range. A DBC range of [0|0]
// means "not given". The tolerance is half a raw step, so a value on the grid at the limit
// is in range whatever the rounding of the DBC's decimal text.
bool outside_range(const dbc::DecodedSignal& d) {
  const dbc::Signal& s = *d.signal;
  if (s.minimum == 0.0 && s.maximum == 0.0) {
    return false;
  }
  const double tolerance = s.value_type == dbc::ValueType::kInteger ? 0.5 * std::fabs(s.factor) : 0.0;
  return !(d.value >= s.minimum - tolerance && d.value <= s.maximum + tolerance);
}

void write_signal_value(JsonWriter& json, const dbc::DecodedSignal& d) {
  const dbc::Signal& s = *d.signal;
  // Integer signals with a unit factor print exactly (a 32-bit sequence has ten digits).
  if (s.value_type == dbc::ValueType::kInteger && s.factor == 1.0 && s.offset == 0.0) {
    json.value(d.raw);
  } else {
    json.value(d.value);
  }
}

class Decoder {
 public:
  Decoder(const dbc::Database& db, const DecodeOptions& options) : db_(db), options_(options) {
    counts_.per_message.assign(db.messages.size(), 0);
  }

  // `too_long`: the line was cut (TextInput::next_line), so it is no frame whatever it holds.
  void line(std::string_view raw_line, bool too_long = false) {
    while (!raw_line.empty() && (raw_line.back() == '\n' || raw_line.back() == '\r')) {
      raw_line.remove_suffix(1);
    }
    ++counts_.lines;
    const candump::ParseResult parsed = TextInput::parse_candump(raw_line, too_long);
    if (!parsed.ok()) {
      const bool blank = !too_long && raw_line.find_first_not_of(" \t") == std::string_view::npos;
      if (!blank) {
        ++counts_.malformed;
        if (counts_.malformed <= kMaxReportedBadLines) {
          std::fprintf(stderr, "decode: line %llu is not a candump frame: %s\n",
                       static_cast<unsigned long long>(counts_.lines), parsed.error.c_str());
        }
        if (counts_.malformed == kMaxReportedBadLines + 1) {
          std::fprintf(stderr, "decode: more lines are not candump frames; the first %d are listed, the summary counts "
                       "them all (--json gives each its error)\n", kMaxReportedBadLines);
        }
      }
      emit(raw_line, blank ? LineKind::kBlank : LineKind::kMalformed, nullptr, nullptr, {}, parsed.error);
      return;
    }
    ++counts_.frames;
    const candump::Record& record = *parsed.record;
    if (record.frame.error) {
      ++counts_.error_frames;
      emit(raw_line, LineKind::kErrorFrame, &record, nullptr, {}, {});
      return;
    }
    const std::optional<dbc::DecodedFrame> decoded = dbc::decode(db_, record.frame);
    if (!decoded) {
      ++counts_.unknown;
      count_other_node(record.frame);
      emit(raw_line, LineKind::kUnknown, &record, nullptr, {}, {});
      return;
    }
    const auto index = static_cast<std::size_t>(decoded->message - db_.messages.data());
    ++counts_.per_message[index];
    std::string out_of_range;
    for (const dbc::DecodedSignal& d : decoded->signals) {
      if (outside_range(d)) {
        out_of_range += (out_of_range.empty() ? "" : ", ") + d.signal->name;
      }
    }
    // A DBC tool cannot check the E2E protection of the commands; the project's codec can: a
    // frame of the protocol whose CRC-8 does not match is corrupt, whatever its signals say.
    // Likewise the alive counter, per command stream (CAN ID), as the daemon checks it.
    bool crc_mismatch = false;
    hal::protocol::DecodeStatus counter = hal::protocol::DecodeStatus::kOk;
    if (!decoded->length_mismatch && !decoded->format_mismatch) {
      hal::protocol::AnyDecoded any;
      const hal::protocol::DecodeStatus status = hal::protocol::decode_any(record.frame, any);
      crc_mismatch = status == hal::protocol::DecodeStatus::kBadCrc;
      // (A command whose CRC held but whose value is out of range advances its stream too, as
      // the daemon's; its range is reported below.)
      const bool identified = status == hal::protocol::DecodeStatus::kOk || status == hal::protocol::DecodeStatus::kOutOfRange;
      if (identified && hal::protocol::message_def(any.type).e2e) {
        counter = counters_[record.frame.id].check(any.alive_counter);
      }
    }
    if (crc_mismatch) {
      out_of_range += (out_of_range.empty() ? "" : ", ") + std::string("Crc (CRC-8 does not match: corrupt frame)");
    }
    if (counter != hal::protocol::DecodeStatus::kOk) {
      out_of_range += (out_of_range.empty() ? "" : ", ") +
                      fmt::format("AliveCounter ({}: {})", hal::protocol::to_string(counter), hal::protocol::describe(counter));
    }
    LineKind kind = LineKind::kDecoded;
    if (crc_mismatch) {
      ++counts_.bad_crc;
      kind = LineKind::kOutOfRange;
    } else if (counter != hal::protocol::DecodeStatus::kOk) {
      ++counts_.bad_counter;
      kind = LineKind::kOutOfRange;
    } else if (decoded->length_mismatch || decoded->format_mismatch) {
      ++counts_.mismatched;
      kind = LineKind::kMismatch;
    } else if (!out_of_range.empty()) {
      ++counts_.out_of_range;
      kind = LineKind::kOutOfRange;
    } else {
      ++counts_.decoded;
    }
    emit(raw_line, kind, &record, &*decoded, out_of_range, {});
  }

  [[nodiscard]] const Counts& counts() const noexcept { return counts_; }

  void print_summary(const std::string& dbc_path, const std::string& input_name) const {
    const Counts& c = counts_;
    if (options_.json) {
      JsonWriter json;
      json.begin_object()
          .field("dbc", dbc_path)
          .field("input", input_name)
          .field("lines", c.lines)
          .field("frames", c.frames)
          .field("decoded", c.decoded)
          .field("unknown", c.unknown)
          .field("error_frames", c.error_frames)
          .field("malformed", c.malformed)
          .field("mismatched", c.mismatched)
          .field("out_of_range", c.out_of_range)
          .field("bad_crc", c.bad_crc)
          .field("bad_counter", c.bad_counter)
          .key("messages")
          .begin_object();
      for (std::size_t i = 0; i < db_.messages.size(); ++i) {
        if (c.per_message[i] != 0U) {
          json.field(db_.messages[i].name, c.per_message[i]);
        }
      }
      json.end_object().end_object();
      std::fprintf(stderr, "%s\n", json.str().c_str());
      return;
    }
    std::string text = fmt::format(
        "decode: {} line(s), {} frame(s): {} decoded, {} unknown, {} error frame(s), {} mismatched "
        "(length or CAN FD/classic), {} out of range, {} with a bad CRC, {} with a bad alive counter, {} malformed line(s)\n",
        c.lines, c.frames, c.decoded, c.unknown, c.error_frames, c.mismatched, c.out_of_range, c.bad_crc, c.bad_counter,
        c.malformed);
    for (std::size_t i = 0; i < db_.messages.size(); ++i) {
      if (c.per_message[i] != 0U) {
        text += fmt::format("  {:<22} {}\n", db_.messages[i].name, c.per_message[i]);
      }
    }
    for (std::size_t node = 0; node < other_node_frames_.size(); ++node) {
      if (other_node_frames_[node] != 0U) {
        text += fmt::format(
            "  {} unknown frame(s) are this DBC's messages for node {} (CAN ID = base + node): decode them with that "
            "node's DBC, `pmsm-thermal dbc --node {} -o node{}.dbc`\n",
            other_node_frames_[node], node, node, node);
      }
    }
    std::fputs(text.c_str(), stderr);
  }

 private:
  void emit(std::string_view raw_line, LineKind kind, const candump::Record* record, const dbc::DecodedFrame* decoded,
            const std::string& out_of_range, const std::string& parse_error) {
    if (options_.quiet) {
      return;
    }
    if (options_.json) {
      if (kind != LineKind::kBlank) {
        emit_json(raw_line, kind, record, decoded, out_of_range, parse_error);
      }
      return;
    }
    std::string text(raw_line);
    switch (kind) {
      case LineKind::kBlank:
      case LineKind::kMalformed:
        break;
      case LineKind::kErrorFrame:
      case LineKind::kUnknown:
        // The library's wording, so that this tool and decode_line() agree.
        text = candump::decode_line(db_, raw_line).text;
        break;
      case LineKind::kMismatch:
      case LineKind::kOutOfRange:
      case LineKind::kDecoded:
        text += " :: ";
        text += dbc::format_single_line(*decoded);
        if (!out_of_range.empty()) {
          text += " [out of range: " + out_of_range + "]";
        }
        break;
    }
    // Every line as it came, but not a log's terminal escapes to the reader's terminal: its
    // control characters (an ASCII column's, a carriage return's, a malformed line's) as \xNN.
    text = common::printable_excerpt(text, text.size(), /*keep_tabs=*/true);
    text += '\n';
    std::fwrite(text.data(), 1, text.size(), stdout);
  }

  void emit_json(std::string_view raw_line, LineKind kind, const candump::Record* record,
                 const dbc::DecodedFrame* decoded, const std::string& out_of_range, const std::string& parse_error) {
    static constexpr std::string_view kStatus[] = {"blank", "malformed", "error_frame", "unknown",
                                                   "mismatch", "out_of_range", "ok"};
    JsonWriter json;
    json.begin_object()
        .field("line_no", counts_.lines)
        .field("text", raw_line)
        .field("status", kStatus[static_cast<std::size_t>(kind)]);
    if (kind == LineKind::kMalformed) {
      json.field("error", parse_error);
    }
    if (record != nullptr) {
      if (record->timestamp) {
        // Integer nanoseconds: a double in %.10g would lose the microseconds of an epoch time.
        json.field("timestamp_ns", std::int64_t{record->timestamp->count()});
      }
      json.field("interface", record->interface)
          .field("id", std::uint64_t{record->frame.id})
          .field("extended", record->frame.extended)
          .field("fd", record->frame.fd)
          .field("length", std::uint64_t{record->frame.length});
    }
    if (decoded != nullptr) {
      json.field("message", decoded->message->name);
      json.key("signals").begin_object();
      for (const dbc::DecodedSignal& d : decoded->signals) {
        json.key(d.signal->name);
        write_signal_value(json, d);
      }
      json.end_object();
      json.key("labels").begin_object();
      for (const dbc::DecodedSignal& d : decoded->signals) {
        if (d.label != nullptr) {
          json.field(d.signal->name, d.label->label);
        }
      }
      json.end_object();
      json.key("units").begin_object();
      for (const dbc::DecodedSignal& d : decoded->signals) {
        if (!d.signal->unit.empty()) {
          json.field(d.signal->name, d.signal->unit);
        }
      }
      json.end_object();
      if (decoded->length_mismatch) {
        json.field("length_mismatch", true);
      }
      if (decoded->format_mismatch) {
        json.field("format_mismatch", true);
      }
      if (!out_of_range.empty()) {
        json.field("out_of_range", out_of_range);
      }
    }
    json.end_object();
    std::string text = json.str();
    text += '\n';
    std::fwrite(text.data(), 1, text.size(), stdout);
  }

  // The protocol's IDs are a base (a multiple of 0x10) plus the node id: an unknown 11-bit frame
  // whose base is one of this DBC's messages belongs to another axis, which the summary says
  // (a node-0 DBC on node 1's traffic decoded nothing and said only "unknown").
  void count_other_node(const hal::CanFrame& frame) {
    if (frame.extended || frame.id > 0x7FFU || !one_node_dbc_) {
      return;
    }
    const std::uint32_t base = frame.id & ~std::uint32_t{0xF};
    for (const dbc::Message& m : db_.messages) {
      if (!m.extended && (m.id & ~std::uint32_t{0xF}) == base && m.id != frame.id) {
        ++other_node_frames_[frame.id & 0xFU];
        return;
      }
    }
  }

  // A DBC shaped like the protocol's: standard IDs that all carry one node (the same low four
  // bits). Another DBC's neighbouring IDs are no other axis.
  [[nodiscard]] static bool one_node(const dbc::Database& db) {
    return !db.messages.empty() && std::all_of(db.messages.begin(), db.messages.end(), [&](const dbc::Message& m) {
      return !m.extended && (m.id & 0xFU) == (db.messages.front().id & 0xFU);
    });
  }

  const dbc::Database& db_;
  const bool one_node_dbc_ = one_node(db_);
  std::array<std::uint64_t, 16> other_node_frames_{};
  const DecodeOptions& options_;
  std::map<std::uint32_t, hal::protocol::AliveCounterCheck> counters_;  // per command CAN ID
  Counts counts_;
};

int run_decode(const DecodeOptions& o) {
  std::string dbc_path = o.dbc_path;
  if (dbc_path.empty()) {
    std::string looked_in;
    const std::optional<fs::path> found = find_default_dbc(looked_in);
    if (!found) {
      std::fprintf(stderr, "decode: no DBC file given and none found (looked in %s); pass --dbc FILE\n",
                   looked_in.c_str());
      return kExitInput;
    }
    dbc_path = found->string();
  }
  dbc::Database db;
  try {
    db = dbc::load(dbc_path);
  } catch (const dbc::ParseError& e) {
    // what() is "FILE:LINE: message", or "FILE: cannot ..." when it could not be read.
    std::fprintf(stderr, "decode: cannot read the DBC: %s\n", e.what());
    return kExitInput;
  }
  if (db.messages.empty()) {
    // An empty file, or one that is no DBC: every frame would be "unknown", exit 0.
    std::fprintf(stderr, "decode: the DBC %s defines no messages (no BO_ line): nothing could be decoded\n",
                 dbc_path.c_str());
    return kExitInput;
  }

  TextInput input;
  if (const std::string problem = input.open(o.input); !problem.empty()) {
    std::fprintf(stderr, "decode: %s\n", problem.c_str());
    return kExitInput;
  }

  Decoder decoder(db, o);
  std::string line;
  for (bool too_long = false; input.next_line(line, too_long);) {
    decoder.line(line, too_long);
  }
  if (input.failed()) {
    std::fprintf(stderr, "decode: error reading '%s'\n", input.name().c_str());
    return kExitInput;
  }
  std::fflush(stdout);
  decoder.print_summary(dbc_path, input.from_stdin() ? "-" : o.input);
  if (decoder.counts().frames == 0U && decoder.counts().malformed != 0U) {
    // Not one frame: this is no capture (a binary file, the wrong file), whatever --strict says.
    std::fprintf(stderr, "decode: %s\n", input.no_frame_error().c_str());
    return kExitInput;
  }
  if (o.strict && decoder.counts().bad() != 0U) {
    std::fprintf(stderr, "decode: --strict: %llu line(s) were not cleanly decoded frames\n",
                 static_cast<unsigned long long>(decoder.counts().bad()));
    return kExitStrict;
  }
  return 0;
}

}  // namespace

void register_decode_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<DecodeOptions>();
  CLI::App* cmd = app.add_subcommand(
      "decode", "Decode candump output (default, -ta, -L, ...) through a DBC, like cantools decode --single-line");
  cmd->add_option("file", options->input, "candump output to read; '-' or none: stdin")
      ->capture_default_str()
      ->check(pmsm::cli::file_name());
  cmd->add_option("--dbc", options->dbc_path,
                  "DBC file (default: share/pmsm-thermal/pmsm-thermal.dbc of the installation, or can/pmsm-thermal.dbc "
                  "of the source tree)")
      ->check(pmsm::cli::file_name());
  cmd->add_flag("--json", options->json, "one JSON object per input line (JSON Lines); JSON summary on stderr");
  cmd->add_flag("--strict", options->strict,
                "exit 1 if any line is not a cleanly decoded frame (unknown ID, error frame, length/format "
                "mismatch, out-of-range signal, malformed line)");
  cmd->add_flag("--quiet", options->quiet, "print only the summary");
  cmd->callback([options, &exit_code] { exit_code = run_decode(*options); });
}

}  // namespace pmsm::app
