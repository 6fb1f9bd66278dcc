#include "calibration_file.hpp"

#include "config_types.hpp"
#include "text_file.hpp"
#include "pmsm/core/machine_equations.hpp"
#include "toml_depth.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iterator>
#include <set>
#include <string_view>
#include <sstream>

#include <fmt/format.h>
#include <toml++/toml.h>

namespace pmsm::app {
namespace {

std::string errno_text(int e) { return std::strerror(e); }

std::string utc_now() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

// TOML basic string: quotes, backslashes and control characters escaped.
std::string quoted(std::string_view text) {
  std::string out = "\"";
  for (const char ch : text) {
    const auto c = static_cast<unsigned char>(ch);
    if (ch == '"' || ch == '\\') {
      out += '\\';
      out += ch;
    } else if (c < 0x20 || c == 0x7f) {
      out += fmt::format("\\u{:04x}", c);
    } else {
      out += ch;
    }
  }
  return out + "\"";
}

// The shortest text that reads back as the same double, always a TOML float.
std::string toml_float(double v) {
  std::string text = fmt::format("{}", v);
  if (text.find_first_of(".eE") == std::string::npos) {
    text += ".0";
  }
  return text;
}

void write_all(int fd, const std::string& text, const std::filesystem::path& tmp) {
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0) {
      if (errno == EINTR) {
        continue;
      }
      throw CalibrationFileError(fmt::format("{}: cannot write: {}", tmp.string(), errno_text(errno)));
    }
    done += static_cast<std::size_t>(n);
  }
}

// Removes the temporary file unless released (the rename consumed it).
class TempFile {
 public:
  explicit TempFile(std::filesystem::path path) : path_(std::move(path)) {}
  TempFile(const TempFile&) = delete;
  TempFile& operator=(const TempFile&) = delete;
  ~TempFile() {
    if (fd_ >= 0) {
      ::close(fd_);
    }
    if (!released_) {
      ::unlink(path_.c_str());
    }
  }
  void open() {
    fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd_ < 0) {
      throw CalibrationFileError(fmt::format("{}: cannot create: {}", path_.string(), errno_text(errno)));
    }
  }
  void close_checked() {
    const int fd = fd_;
    fd_ = -1;
    if (::close(fd) != 0) {
      throw CalibrationFileError(fmt::format("{}: cannot close: {}", path_.string(), errno_text(errno)));
    }
  }
  [[nodiscard]] int fd() const { return fd_; }
  void release() { released_ = true; }

 private:
  std::filesystem::path path_;
  int fd_ = -1;
  bool released_ = false;
};

// A stored key's range: the reader refuses a file with a value outside it, and the writer refuses
// to store one (a file it wrote would otherwise stop the next start).
struct KeyRange {
  const char* key;
  double lo;
  double hi;
  bool lo_open = false;  // (lo, hi] rather than [lo, hi]
  [[nodiscard]] bool holds(double v) const noexcept { return std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi; }
  [[nodiscard]] std::string text() const { return fmt::format("{}{}, {}]", lo_open ? "(" : "[", lo, hi); }
};
constexpr KeyRange kRs0Range{"rs0_ohm", common::kMinStatorResistance_ohm, common::kMaxStatorResistance_ohm, false};
constexpr KeyRange kT0Range{"t0_C", -50.0, 200.0, false};
constexpr KeyRange kT0RiseStdRange{"t0_rise_std_C", 0.0, 100.0, true};         // written only when > 0
constexpr KeyRange kKe0Range{"ke0_V_s_per_rad", 0.0, 100.0, false};
constexpr KeyRange kKe0StdRange{"ke0_std_V_s_per_rad", 0.0, 100.0, false};
constexpr KeyRange kBandRange{"dead_time_band_A", 0.0, 1000.0, true};          // written only when > 0
constexpr KeyRange kAngleRange{"angle_correction_rad", -1.0, 1.0, false};
constexpr KeyRange kVxRange{"vx_V", -50.0, 50.0, false};
constexpr KeyRange kVxStdRange{"vx_std_V", 0.0, 100.0, true};                  // written only when > 0
constexpr KeyRange kVxBusRange{"vx_bus_V", 0.0, 10000.0, true};                // written only when > 0

double number(const toml::table& t, const char* key, const std::string& file, double lo, double hi, bool lo_open) {
  const toml::node* node = t.get(key);
  if (node == nullptr) {
    throw CalibrationFileError(fmt::format("{}: {}: missing", file, key));
  }
  const auto line = node->source().begin.line;
  const std::optional<double> v = node->value<double>();
  if (!v || !node->is_number()) {
    throw CalibrationFileError(fmt::format("{}:{}: {}: expected a number", file, line, key));
  }
  if (const KeyRange range{key, lo, hi, lo_open}; !range.holds(*v)) {
    throw CalibrationFileError(fmt::format("{}:{}: {}: {} is out of range, expected in {}", file, line, key, *v, range.text()));
  }
  return *v;
}

double number(const toml::table& t, const KeyRange& r, const std::string& file) {
  return number(t, r.key, file, r.lo, r.hi, r.lo_open);
}

std::int64_t integer(const toml::table& t, const char* key, const std::string& file, std::int64_t lo, std::int64_t hi) {
  const toml::node* node = t.get(key);
  if (node == nullptr) {
    throw CalibrationFileError(fmt::format("{}: {}: missing", file, key));
  }
  const auto line = node->source().begin.line;
  const std::optional<std::int64_t> v = node->is_integer() ? node->value<std::int64_t>() : std::nullopt;
  if (!v) {
    throw CalibrationFileError(fmt::format("{}:{}: {}: expected an integer", file, line, key));
  }
  if (*v < lo || *v > hi) {
    throw CalibrationFileError(fmt::format("{}:{}: {}: {} is out of range, expected in [{}, {}]", file, line, key, *v, lo, hi));
  }
  return *v;
}

// The axis a stored file belongs to: a CAN node of the protocol (docs/protocol.md) on a named
// interface.
constexpr std::int64_t kMaxStoredNode = 15;

std::string printable(std::string_view text) {
  std::string shown;
  for (const char c : text) {
    shown += std::isprint(static_cast<unsigned char>(c)) != 0 ? c : '?';
  }
  return shown;
}

// Why `name` cannot be an interface's name as a stored file keeps it, or "": Linux's 1..15
// characters, none of them a space, '/', a quote, a backslash or a control character.
std::string stored_interface_problem(std::string_view name) {
  if (name.empty() || name.size() > 15) {
    return fmt::format("\"{}\" is no interface name (1 to 15 characters)", printable(name));
  }
  for (const char c : name) {
    const auto u = static_cast<unsigned char>(c);
    if (std::isgraph(u) == 0 || c == '/' || c == '"' || c == '\\') {
      return fmt::format("\"{}\" is no interface name (a space, '/', a quote, a backslash or a control character)",
                         printable(name));
    }
  }
  return {};
}

// The keys of the axis that writes a file: "" when none is recorded, and when the interface's
// name is one the reader would refuse. Linux allows a quote, a backslash or bytes that are not
// UTF-8 in an interface's name, which a TOML string cannot always carry: such an axis stores
// its files unrecorded (any axis's, as before the record) rather than not at all.
std::string axis_keys(const StoredAxis& axis) {
  if (!axis.recorded() || axis.can_node > static_cast<int>(kMaxStoredNode) ||
      !stored_interface_problem(axis.can_interface).empty()) {
    return {};
  }
  return fmt::format("can_interface = \"{}\"\ncan_node = {}\n", axis.can_interface, axis.can_node);
}

// The axis recorded in the file at `path` if it is a readable file of the kind `read` reads
// (not recorded otherwise: none there, damaged, unrecorded).
template <typename Read>
StoredAxis axis_of_existing(const std::filesystem::path& path, Read read) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    return {};
  }
  try {
    return read(path);
  } catch (const CalibrationFileError&) {
    return {};  // damaged: written over, as before
  }
}

// Refuses to write over a file another axis wrote (two configurations naming one file: the
// first to write keeps it, and the other's writes fail with this, logged).
void refuse_other_axis(const std::filesystem::path& path, const StoredAxis& there, const StoredAxis& mine,
                       std::string_view what) {
  if (there.recorded() && mine.recorded() && !(there == mine)) {
    throw CalibrationFileError(fmt::format("{} is the {} of the axis on {} node {}, not this one's ({} node {}): not written "
                                           "over (name a file of this axis's own)",
                                           path.string(), what, there.can_interface, there.can_node, mine.can_interface,
                                           mine.can_node));
  }
}

StoredAxis read_axis(const toml::table& t, const std::string& file) {
  const toml::node* interface_node = t.get("can_interface");
  const bool node_present = t.get("can_node") != nullptr;
  if ((interface_node != nullptr) != node_present) {
    throw CalibrationFileError(fmt::format("{}: {} is missing (the axis that wrote the file comes as can_interface and "
                                           "can_node, or not at all)",
                                           file, node_present ? "can_interface" : "can_node"));
  }
  StoredAxis axis;
  if (node_present) {
    const auto line = interface_node->source().begin.line;
    const std::optional<std::string> name = interface_node->value<std::string>();
    if (!name) {
      throw CalibrationFileError(fmt::format("{}:{}: can_interface: expected a string", file, line));
    }
    if (const std::string bad = stored_interface_problem(*name); !bad.empty()) {
      throw CalibrationFileError(fmt::format("{}:{}: can_interface: {}", file, line, bad));
    }
    axis.can_interface = *name;
    axis.can_node = static_cast<int>(integer(t, "can_node", file, 0, kMaxStoredNode));
  }
  return axis;
}

// Replaces `path` with `text`: temporary file in the same directory, fsync, rename, directory
// fsync, so that a power cut leaves the old content or the new, never a torn file.
// A writer killed between creating its temporary and the rename (SIGKILL, power loss) leaves
// ".NAME.tmp.PID.N" behind; each restart has a new PID, so they would pile up. The next write
// removes those whose process is gone (the drive is the file's only writer). Errors reading
// the directory end the clean-up quietly: it is housekeeping, not the write.
void remove_stale_temporaries(const std::filesystem::path& dir, const std::string& name) {
  const std::string prefix = "." + name + ".tmp.";
  std::error_code ec;
  std::filesystem::directory_iterator it(dir, ec);
  for (; !ec && it != std::filesystem::directory_iterator(); it.increment(ec)) {
    const std::string file = it->path().filename().string();
    if (file.rfind(prefix, 0) != 0) {
      continue;
    }
    const char* digits = file.c_str() + prefix.size();
    char* end = nullptr;
    const long pid = std::strtol(digits, &end, 10);
    if (end == digits || (*end != '\0' && *end != '.') || pid <= 0) {
      continue;
    }
    if (::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
      std::error_code ignored;
      std::filesystem::remove(it->path(), ignored);
    }
  }
}

void write_atomically(const std::filesystem::path& path, const std::string& text) {
  const std::filesystem::path dir = path.has_parent_path() ? path.parent_path() : std::filesystem::path(".");
  remove_stale_temporaries(dir, path.filename().string());
  // Unique per process and per write: threads of one process (simulate -j) may write at once.
  static std::atomic<unsigned> writes{0};
  const std::filesystem::path tmp =
      dir / fmt::format(".{}.tmp.{}.{}", path.filename().string(), ::getpid(), writes.fetch_add(1, std::memory_order_relaxed));
  TempFile file(tmp);
  file.open();
  write_all(file.fd(), text, tmp);
  if (::fsync(file.fd()) != 0) {
    throw CalibrationFileError(fmt::format("{}: cannot flush: {}", tmp.string(), errno_text(errno)));
  }
  file.close_checked();
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    throw CalibrationFileError(fmt::format("{}: cannot replace: {}", path.string(), errno_text(errno)));
  }
  file.release();
  // The rename is durable only once the directory entry is: a failure here is reported (the
  // new file is in place, but a power loss may bring the old one back).
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0) {
    throw CalibrationFileNotDurable(fmt::format("{}: replaced, but its directory {} cannot be opened to flush it: {}",
                                           path.string(), dir.string(), errno_text(errno)));
  }
  const int flushed = ::fsync(dfd);
  const int flush_errno = errno;
  ::close(dfd);
  if (flushed != 0) {
    throw CalibrationFileNotDurable(fmt::format("{}: replaced, but its directory {} cannot be flushed (a power loss may bring "
                                           "the old file back): {}",
                                           path.string(), dir.string(), errno_text(flush_errno)));
  }
}


}  // namespace

void write_calibration_file(const std::filesystem::path& path, const core::Calibration& c, std::string_view source,
                            const StoredAxis& axis) {
  if (path.empty()) {
    throw CalibrationFileError("calibration file: no path given");
  }
  // Every key the file will hold within the range the reader accepts.
  const std::pair<const KeyRange*, double> stored[] = {
      {&kRs0Range, c.rs0_ohm},
      {&kT0Range, c.t0_C},
      {c.t0_rise_std_C != 0.0 ? &kT0RiseStdRange : nullptr, c.t0_rise_std_C},
      {&kKe0Range, c.ke0_V_s_per_rad},
      {&kKe0StdRange, c.ke0_std_V_s_per_rad},
      {c.dead_time_band_A != 0.0 ? &kBandRange : nullptr, c.dead_time_band_A},
      {c.angle_correction_measured ? &kAngleRange : nullptr, c.angle_correction_rad},
      {c.vx_std_V != 0.0 ? &kVxRange : nullptr, c.vx_V},
      {c.vx_std_V != 0.0 ? &kVxStdRange : nullptr, c.vx_std_V},
      {c.vx_std_V != 0.0 && c.vx_bus_V != 0.0 ? &kVxBusRange : nullptr, c.vx_bus_V},
  };
  for (const auto& [range, value] : stored) {
    if (range != nullptr && !range->holds(value)) {
      throw CalibrationFileError(fmt::format("{}: refusing to store an invalid calibration: {} = {} is outside {}, which "
                                             "the reader would refuse at the next start (Rs0 {} ohm at T0 {} C)",
                                             path.string(), range->key, value, range->text(), c.rs0_ohm, c.t0_C));
    }
  }
  std::ostringstream text;
  text << "# pmsm-thermal calibration (Eq. 1: Rs = Rs0 (1 + alpha (T - T0))); replaced atomically by the drive\n"
       << "format = " << kCalibrationFileFormat << "\n"
       << "rs0_ohm = " << toml_float(c.rs0_ohm) << "\n"
       << "t0_C = " << toml_float(c.t0_C) << "\n"
       << "ke0_V_s_per_rad = " << toml_float(c.ke0_V_s_per_rad) << "\n";
  if (c.t0_rise_std_C > 0.0) {
    // T0's uncertainty from the thermal model's rise it includes (absent: none; the ambient
    // sensor's own, calibration.t0_std_C, is the configuration's).
    text << "t0_rise_std_C = " << toml_float(c.t0_rise_std_C) << "\n";
  }
  if (c.ke0_std_V_s_per_rad > 0.0) {
    // Ke0's standard error (absent: unknown; the magnet estimate's error bar then assumes one).
    text << "ke0_std_V_s_per_rad = " << toml_float(c.ke0_std_V_s_per_rad) << "\n";
  }
  if (c.dead_time_band_A > 0.0) {
    // The bridge's zero-current band from the calibration's sweep (absent: not measured).
    text << "dead_time_band_A = " << toml_float(c.dead_time_band_A) << "\n";
  }
  if (c.angle_correction_measured) {
    // The rotor-angle check's correction of sensors.encoder_offset_rad (absent: not measured).
    text << "angle_correction_rad = " << toml_float(c.angle_correction_rad) << "\n";
  }
  if (c.vx_std_V > 0.0) {
    // The bridge's voltage error Rs0 was learned with, and its standard error (absent: not
    // learned; the configured prior then holds).
    text << "vx_V = " << toml_float(c.vx_V) << "\n"
         << "vx_std_V = " << toml_float(c.vx_std_V) << "\n";
    if (c.vx_bus_V > 0.0) {
      // The bus it was learned on: vx_std_V is its error there (absent: the reference bus).
      text << "vx_bus_V = " << toml_float(c.vx_bus_V) << "\n";
    }
  }
  text << "written_utc = " << quoted(utc_now()) << "\n"
       << "source = " << quoted(source) << "\n"
       << axis_keys(axis);
  refuse_other_axis(path, axis_of_existing(path, [](const std::filesystem::path& p) {
                      StoredAxis a;
                      (void)read_calibration_file(p, &a);
                      return a;
                    }),
                    axis, "calibration");

  write_atomically(path, text.str());
}

std::string other_axis_problem(const std::string& file, const StoredAxis& stored, const StoredAxis& mine,
                               std::string_view key) {
  if (!stored.recorded() || !mine.recorded() || stored == mine) {
    return {};
  }
  return fmt::format("{} was written by the axis on {} node {}, and this daemon is node {} on {} (does another axis's "
                     "configuration name the same {}?)",
                     file, stored.can_interface, stored.can_node, mine.can_node, mine.can_interface, key);
}

namespace {

// Parses a stored file strictly: TOML, only the known keys, the supported format.
toml::table read_stored(const std::filesystem::path& path, const std::set<std::string, std::less<>>& known) {
  const std::string file = path.string();
  std::string text;
  if (const std::string problem = common::read_text_file(path, text); !problem.empty()) {
    throw CalibrationFileError(fmt::format("{}: {}", file, problem));
  }
  if (const auto deep = common::toml_key_depth_problem(text)) {
    throw CalibrationFileError(common::toml_depth_message(*deep, file));
  }
  toml::table t;
  try {
    t = toml::parse(text, file);
  } catch (const toml::parse_error& e) {
    throw CalibrationFileError(fmt::format("{}:{}: {}", file, e.source().begin.line, e.description()));
  }
  for (const auto& [key, node] : t) {
    if (!known.contains(key.str())) {
      throw CalibrationFileError(fmt::format("{}:{}: unknown key '{}'", file, node.source().begin.line, key.str()));
    }
  }
  const double format = number(t, "format", file, 1, 1e9, false);
  if (format != kCalibrationFileFormat) {
    throw CalibrationFileError(
        fmt::format("{}: format: {} is not supported (this build reads format {})", file, format, kCalibrationFileFormat));
  }
  return t;
}

}  // namespace

core::Calibration read_calibration_file(const std::filesystem::path& path, StoredAxis* axis) {
  const std::string file = path.string();
  const toml::table t =
      read_stored(path, {"format", "rs0_ohm", "t0_C", "t0_rise_std_C", "ke0_V_s_per_rad", "ke0_std_V_s_per_rad", "dead_time_band_A", "angle_correction_rad",
                         "vx_V", "vx_std_V", "vx_bus_V", "written_utc", "source", "can_interface", "can_node"});
  const StoredAxis written_by = read_axis(t, file);
  if (axis != nullptr) {
    *axis = written_by;
  }
  // The record of who wrote it and when: text, if given (a number there is a hand edit gone wrong).
  for (const char* key : {"written_utc", "source"}) {
    if (const toml::node* n = t.get(key); n != nullptr && !n->is_string()) {
      throw CalibrationFileError(fmt::format("{}:{}: {}: expected a string", file, n->source().begin.line, key));
    }
  }
  core::Calibration c;
  c.rs0_ohm = number(t, kRs0Range, file);
  c.t0_C = number(t, kT0Range, file);
  c.t0_rise_std_C = t.get("t0_rise_std_C") != nullptr ? number(t, kT0RiseStdRange, file) : 0.0;
  c.ke0_V_s_per_rad = t.get("ke0_V_s_per_rad") != nullptr ? number(t, kKe0Range, file) : 0.0;
  c.ke0_std_V_s_per_rad =
      t.get("ke0_std_V_s_per_rad") != nullptr ? number(t, kKe0StdRange, file) : 0.0;
  if (t.get("ke0_std_V_s_per_rad") != nullptr && !(c.ke0_V_s_per_rad > 0.0)) {
    throw CalibrationFileError(fmt::format("{}: ke0_std_V_s_per_rad without ke0_V_s_per_rad: the error bar of no Ke0 is "
                                           "a hand edit gone wrong",
                                           file));
  }
  c.dead_time_band_A =
      t.get("dead_time_band_A") != nullptr ? number(t, kBandRange, file) : 0.0;
  c.angle_correction_measured = t.get("angle_correction_rad") != nullptr;
  c.angle_correction_rad = c.angle_correction_measured ? number(t, kAngleRange, file) : 0.0;
  // Vx and its error bar come together: one without the other is a hand edit gone wrong.
  if ((t.get("vx_V") != nullptr) != (t.get("vx_std_V") != nullptr)) {
    throw CalibrationFileError(fmt::format("{}: vx_V and vx_std_V go together (the bridge's voltage and its standard error); "
                                           "the file has only {}",
                                           file, t.get("vx_V") != nullptr ? "vx_V" : "vx_std_V"));
  }
  if (t.get("vx_V") != nullptr) {
    c.vx_V = number(t, kVxRange, file);
    c.vx_std_V = number(t, kVxStdRange, file);
  }
  if (t.get("vx_bus_V") != nullptr) {
    if (t.get("vx_V") == nullptr) {
      throw CalibrationFileError(fmt::format("{}: vx_bus_V is the bus of a stored vx_V, which the file does not have", file));
    }
    c.vx_bus_V = number(t, kVxBusRange, file);
  }
  c.calibrated = true;
  return c;
}

namespace {

// The loss model's errors in a thermal state file, with the ranges the reader accepts (and the
// writer keeps to, so that it never writes what it would refuse). k within the filter's
// [-0.5, 1]; the standard deviations and dP within what any configured prior allows.
// Where the filter's missing loss dP enters the network (core::ThermalObserver: the housing).
constexpr const char* kMissingLossNode = "housing";

// The thermal state's temperatures, its deviation, the ambient and the time of the save, in
// this order (the writer's and the reader's).
constexpr KeyRange kThermalStateKeys[] = {{"winding_C", -60.0, 400.0},
                                          {"housing_C", -60.0, 400.0},
                                          {"winding_std_C", 0.0, 1000.0},
                                          {"ambient_C", -60.0, 200.0},
                                          {"saved_unix_s", 0.0, 1e11}};

constexpr KeyRange kLossKeys[] = {{"missing_loss_W", -1e6, 1e6},
                                 {"missing_loss_std_W", 0.0, 1e6},
                                 {"loss_scale_error", core::ThermalObserver::kMinLossScale,
                                  core::ThermalObserver::kMaxLossScale},
                                 {"loss_scale_std", 0.0, 10.0},
                                 {"loss_correlation", -1.0, 1.0}};

// The cooling path's error g and its deviation: a pair of its own (a file from before g was
// kept has neither), within the filter's bounds.
constexpr KeyRange kCoolingKeys[] = {
    {"cooling_scale_error", core::ThermalObserver::kMinCoolingScale, core::ThermalObserver::kMaxCoolingScale},
    {"cooling_scale_std", 0.0, 10.0}};

// Every value within its key's range (NaN is not).
template <std::size_t N>
bool within(const KeyRange (&keys)[N], const double (&values)[N]) {
  for (std::size_t k = 0; k < N; ++k) {
    if (!keys[k].holds(values[k])) {
      return false;
    }
  }
  return true;
}

bool cooling_error_storable(const core::ThermalState& s) {
  const double values[] = {s.cooling_scale_error, s.cooling_scale_std};
  return within(kCoolingKeys, values);
}

bool loss_errors_storable(const core::ThermalState& s) {
  const double values[] = {s.missing_loss_W, s.missing_loss_std_W, s.loss_scale_error, s.loss_scale_std,
                           s.loss_correlation};
  return within(kLossKeys, values);
}

}  // namespace

namespace {
constexpr std::string_view kThermalStateHeader = "# pmsm-thermal thermal state";
}  // namespace

namespace {

// Why the file at `path` is no thermal state file the drive wrote ("" where it is one, or none
// is there, or it is empty, or unreadable): not a regular file, or not starting with the header.
std::string not_a_thermal_state_file(const std::filesystem::path& path) {
  std::error_code ec;
  const std::filesystem::file_type type = std::filesystem::status(path, ec).type();
  if (type == std::filesystem::file_type::not_found) {
    return {};
  }
  if (type != std::filesystem::file_type::regular) {
    // (Opened, a FIFO would block until a writer came; /dev/null would be replaced by the rename.)
    return fmt::format("{} is there and is not a regular file", path.string());
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return {};  // unreadable: the write (or the read) says why
  }
  std::string first(kThermalStateHeader.size(), '\0');
  in.read(first.data(), static_cast<std::streamsize>(first.size()));
  first.resize(static_cast<std::size_t>(in.gcount()));
  if (first.empty() || first == kThermalStateHeader) {
    return {};
  }
  return fmt::format("{} is there and is no thermal state file (it starts \"{}\", not \"{}\")", path.string(),
                     printable(first.substr(0, first.find('\n'))), kThermalStateHeader);
}

}  // namespace

std::string foreign_thermal_state_file(const std::filesystem::path& path) {
  const std::string why = not_a_thermal_state_file(path);
  return why.empty() ? why : why + ": not written over";
}

void write_thermal_state_file(const std::filesystem::path& path, const StoredThermalState& stored) {
  if (path.empty()) {
    throw CalibrationFileError("thermal state file: no path given");
  }
  if (const std::string why = foreign_thermal_state_file(path); !why.empty()) {
    throw CalibrationFileError(why);
  }
  const core::ThermalState& s = stored.state;
  // Every temperature within the range the reader accepts: a state it would refuse would cost
  // the next start its warm restart.
  const double kept[] = {s.winding_C, s.housing_C, s.winding_std_C, stored.ambient_C, stored.saved_unix_s};
  for (std::size_t k = 0; k < std::size(kThermalStateKeys); ++k) {
    if (!kThermalStateKeys[k].holds(kept[k])) {
      throw CalibrationFileError(fmt::format("{}: refusing to store an invalid thermal state: {} = {} is outside {}, which "
                                             "the reader would refuse at the next start (winding {} +- {} C, housing {} C)",
                                             path.string(), kThermalStateKeys[k].key, kept[k],
                                             kThermalStateKeys[k].text(), s.winding_C, s.winding_std_C, s.housing_C));
    }
  }
  std::ostringstream text;
  text << kThermalStateHeader << "; replaced atomically by the drive\n"
       << "format = " << kCalibrationFileFormat << "\n"
       << "winding_C = " << toml_float(s.winding_C) << "\n"
       << "housing_C = " << toml_float(s.housing_C) << "\n"
       << "winding_std_C = " << toml_float(s.winding_std_C) << "\n"
       << "ambient_C = " << toml_float(stored.ambient_C) << "\n"
       << "saved_unix_s = " << toml_float(stored.saved_unix_s) << "\n";
  if (s.has_loss_errors && loss_errors_storable(s)) {
    // What the filter learned of the loss model (absent: the priors at the restart), and where
    // its missing loss enters the network: a dP learned on the winding (a file written before
    // dP moved to the housing has no such key) would mean another temperature on the housing.
    text << "missing_loss_node = \"" << kMissingLossNode << "\"\n"
         << "missing_loss_W = " << toml_float(s.missing_loss_W) << "\n"
         << "missing_loss_std_W = " << toml_float(s.missing_loss_std_W) << "\n"
         << "loss_scale_error = " << toml_float(s.loss_scale_error) << "\n"
         << "loss_scale_std = " << toml_float(s.loss_scale_std) << "\n"
         << "loss_correlation = " << toml_float(s.loss_correlation) << "\n";
  }
  if (s.has_cooling_error && cooling_error_storable(s)) {
    text << "cooling_scale_error = " << toml_float(s.cooling_scale_error) << "\n"
         << "cooling_scale_std = " << toml_float(s.cooling_scale_std) << "\n";
  }
  text << axis_keys(stored.axis);
  refuse_other_axis(path, axis_of_existing(path, [](const std::filesystem::path& p) { return read_thermal_state_file(p).axis; }),
                    stored.axis, "thermal state");
  write_atomically(path, text.str());
}

StoredThermalState read_thermal_state_file(const std::filesystem::path& path) {
  const std::string file = path.string();
  const toml::table t =
      read_stored(path, {"format", "winding_C", "housing_C", "winding_std_C", "ambient_C", "saved_unix_s",
                         "missing_loss_node", "missing_loss_W", "missing_loss_std_W", "loss_scale_error",
                         "loss_scale_std", "loss_correlation", "cooling_scale_error", "cooling_scale_std",
                         "can_interface", "can_node"});
  StoredThermalState s;
  s.state.winding_C = number(t, kThermalStateKeys[0], file);
  s.state.housing_C = number(t, kThermalStateKeys[1], file);
  s.state.winding_std_C = number(t, kThermalStateKeys[2], file);
  s.ambient_C = number(t, kThermalStateKeys[3], file);
  s.saved_unix_s = number(t, kThermalStateKeys[4], file);
  // The loss model's errors: all five or none (a file from before they were kept). A bad
  // block costs only itself: the temperatures hold, the loss errors restart from the priors.
  int present = 0;
  for (const KeyRange& key : kLossKeys) {
    present += t.get(key.key) != nullptr ? 1 : 0;
  }
  if (present != 0) {
    try {
      double values[std::size(kLossKeys)] = {};
      for (std::size_t k = 0; k < std::size(kLossKeys); ++k) {
        if (t.get(kLossKeys[k].key) == nullptr) {
          throw CalibrationFileError(fmt::format("{}: {} is missing (the loss model's errors come as missing_loss_W, "
                                                 "missing_loss_std_W, loss_scale_error, loss_scale_std and "
                                                 "loss_correlation, or not at all)",
                                                 file, kLossKeys[k].key));
        }
        values[k] = number(t, kLossKeys[k], file);
      }
      const std::optional<std::string> node = t["missing_loss_node"].value<std::string>();
      if (node != kMissingLossNode) {
        throw CalibrationFileError(fmt::format(
            "{}: missing_loss_node is {} where this build's filter has \"{}\": its missing loss was learned "
            "on {} (the loss model's errors restart from the priors)",
            file, node ? "\"" + *node + "\"" : std::string("absent"), kMissingLossNode,
            node ? "another node" : "the winding, before it moved to the housing"));
      }
      s.state.has_loss_errors = true;
      s.state.missing_loss_W = values[0];
      s.state.missing_loss_std_W = values[1];
      s.state.loss_scale_error = values[2];
      s.state.loss_scale_std = values[3];
      s.state.loss_correlation = values[4];
    } catch (const CalibrationFileError& e) {
      s.state.has_loss_errors = false;
      s.loss_errors_ignored = e.what();
    }
  }
  // The cooling path's error: both keys or neither, a bad pair costing only itself (g restarts
  // from its prior).
  const bool g_present = t.get(kCoolingKeys[0].key) != nullptr;
  const bool g_std_present = t.get(kCoolingKeys[1].key) != nullptr;
  if (g_present || g_std_present) {
    try {
      if (g_present != g_std_present) {
        throw CalibrationFileError(fmt::format("{}: {} is missing (the cooling path's error comes as cooling_scale_error and "
                                               "cooling_scale_std, or not at all)",
                                               file, g_present ? kCoolingKeys[1].key : kCoolingKeys[0].key));
      }
      s.state.cooling_scale_error = number(t, kCoolingKeys[0], file);
      s.state.cooling_scale_std = number(t, kCoolingKeys[1], file);
      s.state.has_cooling_error = true;
    } catch (const CalibrationFileError& e) {
      s.state.has_cooling_error = false;
      s.cooling_error_ignored = e.what();
    }
  }
  // The axis that wrote it: both keys or neither, and a bad one refuses the file (whose axis
  // it is cannot be told: it is not taken for this one's).
  s.axis = read_axis(t, file);
  // Only what the drive wrote, which starts with its header: a file without it (one written by
  // hand, a copy of something else that happens to parse) is not taken, as it is not written
  // over (foreign_thermal_state_file), which would leave it in place for every start.
  if (const std::string why = not_a_thermal_state_file(path); !why.empty()) {
    throw CalibrationFileError(why + ": not used");
  }
  return s;
}

std::string ke0_off_motor_warning(const core::DriveConfig& config, const core::Calibration& c) {
  const double motor_ke = core::emf_constant_dq_V_s_per_rad(config.motor);
  const double off = c.ke0_V_s_per_rad / motor_ke - 1.0;
  if (!(c.ke0_V_s_per_rad > 0.0) || !std::isfinite(off) || std::abs(off) <= kKe0OffMotorFraction) {
    return {};
  }
  return fmt::format(
      "calibration: Ke0 {} V s/rad (phase peak per mechanical rad/s) is {:+.0f} % off motor.ke_V_s_per_rad's {} V s/rad "
      "in that form ({} line-to-line RMS), beyond the {:.0f} % a magnet's temperature and a data sheet's tolerance "
      "explain. Where this drive measured it, motor.ke_V_s_per_rad is wrong (its EMF feed-forward and voltage limits use "
      "it; the measurement's line-to-line RMS form is {}); otherwise it is another motor's calibration, or other units. "
      "Magnet readings are referred to Ke0",
      common::format_number(c.ke0_V_s_per_rad), 100.0 * off, common::format_number(motor_ke),
      common::format_number(config.motor.ke_V_s_per_rad), 100.0 * kKe0OffMotorFraction,
      common::format_number(c.ke0_V_s_per_rad * std::sqrt(1.5)));
}

std::string rs0_off_nameplate_warning(const core::DriveConfig& config, const core::Calibration& c) {
  // A measured Rs0 well above the configured one is most often a motor cable the configuration
  // does not give: Eq. 1 then takes the cable for winding, and every rise reads low by the
  // cable's share of Rs0.
  const double cable_20C_ohm = config.thermal.cable_resistance_20C_ohm;
  const double expected_ohm =
      core::resistance_at_temperature_ohm(config.motor.rs_ohm, config.motor.rs_reference_temp_C, c.t0_C,
                                          config.thermal.conductor_inferred_zero_C) +
      core::cable_resistance_at_C(cable_20C_ohm, c.t0_C);
  const double off = c.rs0_ohm / expected_ohm - 1.0;
  if (!std::isfinite(off) || std::abs(off) <= kRs0NameplateWarnFraction) {
    return {};
  }
  const bool cable = cable_20C_ohm > 0.0;
  return fmt::format(
      "calibration: Rs0 {:.5f} ohm is {:+.0f} % off motor.rs_ohm{} referred to {:.1f} C ({:.5f} ohm). {}", c.rs0_ohm,
      100.0 * off, cable ? " and motor.cable_resistance_ohm" : "", c.t0_C, expected_ohm,
      off > 0.0 ? (cable ? "More cable than motor.cable_resistance_ohm gives"
                         : "A motor cable the configuration does not give (motor.cable_resistance_ohm)") +
                      std::string(" makes every winding rise read low by its share of Rs0; otherwise the nameplate "
                                  "value is wrong")
                : std::string("Check motor.rs_ohm") + (cable ? " and motor.cable_resistance_ohm" : ""));
}

}  // namespace pmsm::app
