#include "scenario.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <string_view>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <toml++/toml.h>

#include "config_schema.hpp"
#include "key_rules.hpp"
#include "supervisor_config.hpp"
#include "drive_node.hpp"
#include "pmsm/core/thermal_observer.hpp"
#include "text_file.hpp"

namespace pmsm::app {
namespace {

using S = ScenarioConfig;

std::vector<ProfilePoint> to_points(const std::vector<double>& flat) {
  std::vector<ProfilePoint> out;
  for (std::size_t k = 0; k + 1 < flat.size(); k += 2) {
    out.push_back({flat[k], flat[k + 1]});
  }
  return out;
}

std::vector<double> to_flat(const Profile& p) {
  std::vector<double> out;
  for (const ProfilePoint& q : p.points) {
    out.push_back(q.time_s);
    out.push_back(q.value);
  }
  return out;
}

// "file:line: key: " for a node, naming the file it came from (a scenario may inherit it).
std::string where(const toml::node& node, std::string_view source, std::string_view key) {
  const auto& region = node.source();
  const std::string file = region.path && !region.path->empty() ? *region.path : std::string(source);
  const std::string line = region.begin.line > 0 ? ":" + std::to_string(region.begin.line) : "";
  return file + line + ": " + std::string(key) + ": ";
}

// What a set-point profile's value may be: the same bounds as `pmsm-thermal command` puts on
// a set-point, so that a scenario cannot ask the drive for what no supervisor could.
struct ProfileLimits {
  std::string_view unit;
  double lo;
  double hi;
};
constexpr ProfileLimits kSpeedLimits{"rad/s", -2000.0, 2000.0};
constexpr ProfileLimits kTorqueLimits{"Nm", -1000.0, 1000.0};
constexpr double kMaxProfileTime_s = 1e6;  // scenario.duration_s's own upper bound

// Adds one point after checking it: finite, time in [0, 1e6] s and ascending, value within
// the limits. `at` names the file, line and key.
void add_point(Profile& p, double t, double v, const ProfileLimits& limits, const std::string& at) {
  if (!std::isfinite(t) || t < 0.0 || t > kMaxProfileTime_s) {
    throw ConfigError(at + "time must be a number in [0, 1e6] s, got " + common::format_number(t));
  }
  if (!p.points.empty() && t <= p.points.back().time_s) {
    throw ConfigError(at + "times must ascend (" + common::format_number(t) + " after " + common::format_number(p.points.back().time_s) +
                      ")");
  }
  if (!std::isfinite(v) || v < limits.lo || v > limits.hi) {
    throw ConfigError(at + "value must be a number in [" + common::format_number(limits.lo) + ", " + common::format_number(limits.hi) +
                      "] " + std::string(limits.unit) + ", got " + common::format_number(v));
  }
  p.points.push_back({t, v});
}

// Reads a profile given as [[t, v], [t, v], ...]; times must ascend.
Profile read_points(const toml::node& node, std::string_view source, std::string_view key, const ProfileLimits& limits) {
  const std::string at = where(node, source, key);
  const auto* array = node.as_array();
  if (array == nullptr || array->empty()) {
    throw ConfigError(at + "expected a non-empty array of [time_s, value] pairs");
  }
  Profile p;
  std::size_t index = 0;
  for (const toml::node& item : *array) {
    const std::string element = where(item, source, key) + "point " + std::to_string(index++) + ": ";
    const auto* pair = item.as_array();
    if (pair == nullptr || pair->size() != 2) {
      throw ConfigError(element + "every point must be [time_s, value]");
    }
    double v[2] = {0.0, 0.0};
    for (std::size_t k = 0; k < 2; ++k) {
      const toml::node* n = pair->get(k);
      if (n == nullptr) {
        throw ConfigError(element + "every point must hold two numbers");
      }
      if (const auto* i = n->as_integer()) {
        v[k] = static_cast<double>(i->get());
      } else if (const auto* f = n->as_floating_point()) {
        v[k] = f->get();
      } else {
        throw ConfigError(element + "every point must hold two numbers");
      }
    }
    add_point(p, v[0], v[1], limits, element);
  }
  return p;
}

// One CSV cell as a number: the whole cell (spaces around it allowed), nothing after it.
std::optional<double> parse_cell(std::string_view cell) {
  while (!cell.empty() && (cell.front() == ' ' || cell.front() == '\t')) cell.remove_prefix(1);
  while (!cell.empty() && (cell.back() == ' ' || cell.back() == '\t' || cell.back() == '\r')) cell.remove_suffix(1);
  if (cell.empty()) {
    return std::nullopt;
  }
  // Decimal only, as the plant's CSV reader takes it (strtod also took 0x10 as 16); a leading
  // '+' is allowed, from_chars alone does not.
  if (cell.front() == '+' && cell.size() > 1 && cell[1] != '-' && cell[1] != '+') {
    cell.remove_prefix(1);
  }
  double v = 0.0;
  const auto [ptr, ec] = std::from_chars(cell.data(), cell.data() + cell.size(), v);
  if (ec != std::errc{} || ptr != cell.data() + cell.size()) {
    return std::nullopt;
  }
  return v;  // NaN and inf pass here; add_point refuses them with the range
}

// Reads a two-column CSV (time_s, value) with an optional header line; `at` names where it
// was asked for. A row with more or fewer than two cells is refused, not read in part.
Profile read_csv(const std::filesystem::path& path, std::string_view key, const std::string& at,
                 const ProfileLimits& limits) {
  std::string text;
  try {
    text = common::read_config_file(path, "CSV");
  } catch (const ConfigError& e) {
    throw ConfigError(at + e.what());
  }
  std::istringstream in(text);
  Profile p;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (!line.empty() && line.back() == '\r') {
      line.pop_back();
    }
    if (number == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) {
      line.erase(0, 3);  // a UTF-8 byte-order mark (a spreadsheet's export)
    }
    if (line.find_first_not_of(" \t") == std::string::npos) {
      line.clear();  // blank, as an empty line
    }
    // A first line without a digit is a header (docs/scenarios.md); one with a digit is a row,
    // and a malformed row is an error, not a header dropped in silence (",100" was).
    if (line.empty() || line[0] == '#' || (number == 1 && line.find_first_of("0123456789") == std::string::npos)) {
      continue;
    }
    const std::string row_at = path.string() + ":" + std::to_string(number) + ": " + std::string(key) + ": ";
    std::vector<std::string_view> cells;
    std::string_view rest(line);
    for (std::size_t comma; (comma = rest.find(',')) != std::string_view::npos; rest.remove_prefix(comma + 1)) {
      cells.push_back(rest.substr(0, comma));
    }
    cells.push_back(rest);
    if (cells.size() != 2) {
      throw ConfigError(row_at + "expected 2 columns 'time_s,value', got " + std::to_string(cells.size()) + ": '" +
                        common::excerpt(line) + "'");
    }
    const std::optional<double> t = parse_cell(cells[0]);
    const std::optional<double> v = parse_cell(cells[1]);
    if (!t || !v) {
      throw ConfigError(row_at + "expected 'time_s,value' (two numbers), got '" + common::excerpt(line) + "'");
    }
    add_point(p, *t, *v, limits, row_at);
  }
  if (p.points.empty()) {
    throw ConfigError(at + "no data rows in " + path.string());
  }
  return p;
}

ConfigSchema<S> build_schema() {
  ConfigSchema<S> s;
  s.string("scenario.name", [](S& c) -> std::string& { return c.name; }, "Name used in reports.");
  s.string("scenario.description", [](S& c) -> std::string& { return c.description; }, "One line for the reader.");
  s.real("scenario.duration_s", [](S& c) -> double& { return c.duration_s; }, between(0.1, 1e6), "s",
         "Simulated time (at least 0.1 s: the drive's thermal filter, which every estimate and figure goes through, "
         "updates every 10 ms).");
  s.real("scenario.thermal_acceleration", [](S& c) -> double& { return c.thermal_acceleration; }, between(0.001, 1e5), "",
         "Thermal time runs this many times faster, in the plant and in the controller's thermal model alike.");
  s.real("scenario.ambient_C", [](S& c) -> double& { return c.ambient_C; }, between(-40, 80), "C",
         "Ambient temperature; the motor starts soaked at it.");
  s.list("scenario.ambient_profile", 2, 200, between(-1e6, 1e6), [](const S& c) { return to_flat(c.ambient_profile); },
         [](S& c, const std::vector<double>& v) { c.ambient_profile.points = to_points(v); }, "",
         "Ambient over time as a flat list t0, C0, t1, C1, ... (the drive's ambient sensor reads it).");
  s.choice("operation.mode", {{"speed", static_cast<int>(core::DriveMode::kSpeed)}, {"torque", static_cast<int>(core::DriveMode::kTorque)}},
           [](const S& c) { return static_cast<int>(c.mode); },
           [](S& c, int v) { c.mode = static_cast<core::DriveMode>(v); }, "Speed or torque control.");
  s.boolean("operation.calibrate", [](S& c) -> bool& { return c.calibrate; },
            "Calibrate Rs0 (and Ke0) at the start, when the winding is known to be at ambient.");
  s.real("operation.calibrate_at_s", [](S& c) -> double& { return c.calibrate_at_s; }, at_least(0), "s", "When to start the calibration (with operation.calibrate): before scenario.duration_s.");
  s.boolean("operation.calibration_real_time", [](S& c) -> bool& { return c.calibration_real_time; },
            "Run the calibration at real thermal time (no test acceleration), as on a machine; for the plant and the "
            "drive alike (it replaces the drive's controller.thermal.calibration_real_time).");
  s.real("metrics.log_period_s", [](S& c) -> double& { return c.log_period_s; }, positive(100), "s", "Time series and error sampling period.");
  s.real("metrics.error_threshold_C", [](S& c) -> double& { return c.error_threshold_C; }, between(-50, 300), "C",
         "Winding errors count where the true winding temperature is above this.");
  s.real("metrics.disturbance_window_s", [](S& c) -> double& { return c.disturbance_window_s; }, positive(10), "s",
         "How long after an injection a row still counts as disturbed by it, and the half-width of the window in which "
         "the twin without injection must run steadily for a row to be judged (the torque is a 10 ms average; "
         "docs/scenarios.md, Disturbance).");
  s.real("metrics.rated_torque_Nm", [](S& c) -> double& { return c.rated_torque_Nm; }, positive(1e5), "Nm",
         "Torque disturbance is relative to this.");
  return s;
}

const ConfigSchema<S>& schema() {
  static const ConfigSchema<S> s = build_schema();
  return s;
}

// Deep merge of `overrides` into `base`. The nodes are moved, not copied: toml++ keeps a
// node's source position (file and line, for messages) only when it is moved.
void merge(toml::table& base, toml::table&& overrides) {
  for (auto&& [key, node] : overrides) {
    if (auto* sub = node.as_table()) {
      if (auto* existing = base.get_as<toml::table>(key.str())) {
        merge(*existing, std::move(*sub));
        continue;
      }
    }
    base.insert_or_assign(key.str(), std::move(node));
  }
}


// What a plant error message says: its key and the rest, from its first ": key: " (a key is
// [a-z_]+ followed by .[A-Za-z0-9_]+ segments). Scanned by hand: std::regex recurses once per
// character, and a message quoting a 20,000-character value overflowed the stack.
struct KeyMessage {
  std::string key;
  std::string detail;
};

bool lower_key_char(char c) { return (c >= 'a' && c <= 'z') || c == '_'; }
bool key_char(char c) { return lower_key_char(c) || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9'); }

std::optional<KeyMessage> key_message(const std::string& message) {
  for (std::size_t pos = message.find(": "); pos != std::string::npos; pos = message.find(": ", pos + 1)) {
    std::size_t end = pos + 2;
    while (end < message.size() && lower_key_char(message[end])) {
      ++end;
    }
    if (end == pos + 2) {
      continue;
    }
    while (end + 1 < message.size() && message[end] == '.' && key_char(message[end + 1])) {
      ++end;
      while (end < message.size() && key_char(message[end])) {
        ++end;
      }
    }
    if (message.compare(end, 2, ": ") == 0) {
      return KeyMessage{message.substr(pos + 2, end - pos - 2), message.substr(end + 2)};
    }
  }
  return std::nullopt;
}

// Every "section.key" in a message, in order ([a-z_]+ "." [A-Za-z0-9_]+, not overlapping).
std::vector<std::string> dotted_keys(const std::string& message) {
  std::vector<std::string> keys;
  std::size_t i = 0;
  while (i < message.size()) {
    if (!lower_key_char(message[i])) {
      ++i;
      continue;
    }
    std::size_t j = i;
    while (j < message.size() && lower_key_char(message[j])) {
      ++j;
    }
    if (j + 1 < message.size() && message[j] == '.' && key_char(message[j + 1])) {
      std::size_t k = j + 1;
      while (k < message.size() && key_char(message[k])) {
        ++k;
      }
      keys.push_back(message.substr(i, k - i));
      i = k;
    } else {
      i = j;
    }
  }
  return keys;
}

// "(did you mean motor.rs_ohm?)" -> "(did you mean plant.motor.rs_ohm?)".
std::string with_plant_prefix(std::string detail) {
  constexpr std::string_view kAsk = "(did you mean ";
  for (std::size_t pos = detail.find(kAsk); pos != std::string::npos; pos = detail.find(kAsk, pos + 1)) {
    std::size_t end = pos + kAsk.size();
    while (end < detail.size() && (key_char(detail[end]) || detail[end] == '.')) {
      ++end;
    }
    if (end > pos + kAsk.size() && detail.compare(end, 2, "?)") == 0) {
      detail.insert(pos + kAsk.size(), "plant.");
    }
  }
  return detail;
}

// One line of a plant error, pointed at the scenario's own line when its key (or, for a rule
// between keys, the first key it names) is one of the scenario's [plant] overrides.
std::string scenario_line(const std::string& line, const toml::table& plant_table, const std::filesystem::path& source) {
  const std::optional<KeyMessage> km = key_message(line);
  if (!km) {
    return line;
  }
  auto node = plant_table.at_path(km->key);
  for (const std::string& k : dotted_keys(line)) {
    if (node) {
      break;
    }
    node = plant_table.at_path(k);
  }
  if (!node) {
    return line;
  }
  const auto& where = node.node()->source();
  const std::string file = where.path && !where.path->empty() ? *where.path : source.string();
  const std::string at = where.begin.line > 0 ? ":" + std::to_string(where.begin.line) : "";
  // A suggested key is the plant file's; in a scenario it lives under [plant] too.
  return file + at + ": plant." + km->key + ": " + with_plant_prefix(km->detail);
}

// `files` receives the plant profile's path when one is named.
plant::PlantConfig load_plant(const toml::table& root, const std::filesystem::path& source,
                              std::vector<std::filesystem::path>& files) {
  const std::filesystem::path dir = source.parent_path();
  const toml::table* plant_table = common::optional_section(root, "plant", source.string());
  toml::table merged;
  if (plant_table != nullptr) {
    if (const auto profile = (*plant_table)["profile"].value<std::string>()) {
      const std::filesystem::path profile_path = dir / *profile;
      std::string text;
      try {
        text = common::read_config_file(profile_path, "plant profile");
      } catch (const ConfigError& e) {
        // Named at the scenario's line that asks for it (it said "nope.toml: plant profile: no
        // such file", neither the key nor where).
        throw ConfigError(where(*(*plant_table).get("profile"), source.string(), "plant.profile") + e.what());
      }
      files.push_back(profile_path);
      // The profile on its own first, so its own mistakes are reported with its own lines.
      (void)plant::parse_plant_config(text, profile_path.string(), profile_path.parent_path());
      merged = toml::parse(text, profile_path.string());
      // Paths in the profile are relative to the profile.
      if (auto* csv = merged.at_path("load.csv_path").as_string(); csv != nullptr &&
                                                                    std::filesystem::path(csv->get()).is_relative()) {
        *csv = std::filesystem::absolute(profile_path.parent_path() / csv->get()).lexically_normal().string();
      }
    } else if ((*plant_table).contains("profile")) {
      throw ConfigError(source.string() + ": plant.profile: expected a path (string)");
    }
    toml::table overrides = *plant_table;  // a copy: its positions are looked up in plant_table
    overrides.erase("profile");
    merge(merged, std::move(overrides));
  }
  std::ostringstream text;
  text << merged;
  try {
    return plant::parse_plant_config(text.str(), source.string() + " [plant]", dir);
  } catch (const plant::ConfigError& e) {
    // Point at the scenario's own line when the offending key is one of its overrides; the
    // schema lists every bad key of the table, one a line, and each line is pointed alone.
    const std::string message = e.what();
    if (plant_table == nullptr) {
      throw ConfigError(message);
    }
    std::istringstream lines(message);
    std::string out;
    for (std::string line; std::getline(lines, line);) {
      out += (out.empty() ? "" : "\n") + scenario_line(line, *plant_table, source);
    }
    throw ConfigError(out);
  }
}

}  // namespace

double Profile::at(double t_s) const {
  if (points.empty()) {
    return 0.0;
  }
  if (t_s <= points.front().time_s) {
    return points.front().value;
  }
  if (t_s >= points.back().time_s) {
    return points.back().value;
  }
  // The first point after t (the loader keeps the times in order): asked every period, a
  // search from the front cost more the longer the run and the profile (a CSV drive cycle).
  const auto b = std::upper_bound(points.begin() + 1, points.end(), t_s,
                                  [](double t, const ProfilePoint& q) { return t < q.time_s; });
  if (b == points.end()) {
    return points.back().value;
  }
  const ProfilePoint& a = *(b - 1);
  return a.value + (b->value - a.value) * (t_s - a.time_s) / (b->time_s - a.time_s);
}

namespace {

constexpr std::size_t kMaxBases = 8;

std::string chain_text(const std::vector<std::filesystem::path>& chain, const std::filesystem::path& next) {
  std::string text;
  for (const std::filesystem::path& p : chain) {
    text += p.string() + " -> ";
  }
  return text + next.string();
}

// A scenario may name a base scenario (scenario.base, relative to itself) and override only
// what differs; bases may chain, up to kMaxBases. `chain`: the files from the one loaded down
// to `source`, which is its last; each base read is added.
toml::table resolve_base(toml::table root, const std::filesystem::path& source, std::vector<std::filesystem::path>& chain) {
  const auto base = root.at_path("scenario.base").value<std::string>();
  if (!base) {
    if (root.at_path("scenario.base")) {
      throw ConfigError(source.string() + ": scenario.base: expected a path (string)");
    }
    return root;
  }
  const std::filesystem::path base_path = source.parent_path() / *base;
  const std::string at = common::node_location(*root.at_path("scenario.base").node(), source.string()) + "scenario.base: ";
  for (const std::filesystem::path& earlier : chain) {
    if (common::same_file(earlier, base_path)) {
      throw ConfigError(at + "the bases form a cycle: " + chain_text(chain, base_path));
    }
  }
  if (chain.size() > kMaxBases) {
    throw ConfigError(at + "more than " + std::to_string(kMaxBases) + " bases in a chain: " + chain_text(chain, base_path));
  }
  std::string base_text;
  try {
    // A base that cannot be read is the referring file's error: its file and line first, then
    // the path it resolved to (relative to the referring file), as for a CSV.
    base_text = common::read_config_file(base_path, "scenario");
  } catch (const ConfigError& e) {
    throw ConfigError(at + e.what());
  }
  chain.push_back(base_path);
  toml::table merged = resolve_base(common::parse_toml(base_text, base_path.string()), base_path, chain);
  // Paths in the base are relative to the base, not to the file that inherits it.
  for (const char* key : {"plant.profile", "plant.load.csv_path", "operation.speed_csv", "operation.torque_csv",
                          "controller.calibration.file"}) {
    auto node = merged.at_path(key);
    if (auto* text = node.as_string(); text != nullptr && std::filesystem::path(text->get()).is_relative()) {
      *text = std::filesystem::absolute(base_path.parent_path() / text->get()).lexically_normal().string();
    }
  }
  root.get_as<toml::table>("scenario")->erase("base");
  // A set-point profile is inline or from a CSV: a file that gives one, in either form, replaces
  // its base's (which may have used the other form).
  if (toml::table* base_operation = merged["operation"].as_table(); base_operation != nullptr) {
    for (const auto& [inline_key, csv_key] :
         {std::pair{"speed_rad_s", "speed_csv"}, std::pair{"torque_Nm", "torque_csv"}}) {
      const toml::table* own = root["operation"].as_table();
      if (own != nullptr && (own->contains(inline_key) || own->contains(csv_key))) {
        base_operation->erase(inline_key);
        base_operation->erase(csv_key);
      }
    }
  }
  // A file that chooses the mode leaves its base's profile of the other mode behind (a torque
  // scenario built on a speed one need not, and could not, unset the base's speeds).
  if (const toml::table* own = root["operation"].as_table(); own != nullptr) {
    if (const auto mode = own->at_path("mode").value<std::string>(); mode && (*mode == "speed" || *mode == "torque")) {
      if (toml::table* base_operation = merged["operation"].as_table(); base_operation != nullptr) {
        const bool speed = *mode == "speed";
        base_operation->erase(speed ? "torque_Nm" : "speed_rad_s");
        base_operation->erase(speed ? "torque_csv" : "speed_csv");
      }
    }
  }
  // A file that chooses the load profile or the EMF shape leaves its base's tables of the old
  // one behind (the plant refuses a load table or harmonics its choice does not use, and a file
  // has no way to unset an inherited key): a fan load built on a steps scenario.
  struct Choice {
    const char* selector;
    const char* section;
    std::array<const char*, 3> tables;  // (nullptr: none)
  };
  static constexpr std::array<Choice, 2> kChoices{{
      {"plant.load.profile", "plant.load", {"steps", "speed_points", "csv_path"}},
      {"plant.emf.shape", "plant.emf", {"harmonic_orders", "harmonic_amplitudes", nullptr}},
  }};
  for (const Choice& choice : kChoices) {
    if (!root.at_path(choice.selector)) {
      continue;
    }
    if (toml::table* base_section = merged.at_path(choice.section).as_table(); base_section != nullptr) {
      for (const char* key : choice.tables) {
        if (key != nullptr) {
          base_section->erase(key);
        }
      }
    }
  }
  merge(merged, std::move(root));
  return merged;
}

}  // namespace

Scenario parse_scenario(std::string_view toml_text, const std::filesystem::path& source) {
  std::vector<std::filesystem::path> chain{source};
  const toml::table root = resolve_base(common::parse_toml(toml_text, source.string()), source, chain);
  Scenario out;
  out.source = source;
  out.files = std::move(chain);
  // Every part's mistakes in one message, as pmsm-thermald gives its file's: the scenario's own
  // keys, the plant's and the controller's are read apart, each part to its own errors (the
  // plant's and the controller's schemas list every bad key of theirs), and a part that needs
  // another's values waits for them. (A file with a mistyped scenario key and a wrong controller
  // key named only the first.)
  std::string errors;
  auto attempt = [&errors](auto&& part) {
    try {
      part();
      return true;
    } catch (const ConfigError& e) {
      errors += (errors.empty() ? "" : "\n") + std::string(e.what());
      return false;
    }
  };
  const bool scenario_ok = attempt([&] {
    schema().apply(root, out.scenario, source.string(),
                   {"plant", "controller", "supervisor", "scenario.seed", "operation.speed_rad_s", "operation.torque_Nm", "operation.speed_csv",
                    "operation.torque_csv"});
  });
  // The set-points need the scenario's keys (the mode).
  (void)(scenario_ok && attempt([&] {
    // Set-point profiles, inline or from CSV: one of the two (a file replaces its base's, in
    // resolve_base), so both here were given in one file: one would be ignored.
    for (const auto& [inline_key, csv_key] : {std::pair{"operation.speed_rad_s", "operation.speed_csv"},
                                              std::pair{"operation.torque_Nm", "operation.torque_csv"}}) {
      const auto points = root.at_path(inline_key);
      const auto csv = root.at_path(csv_key);
      if (points && csv) {
        throw ConfigError(where(*csv.node(), source.string(), csv_key) + "given together with " + std::string(inline_key) +
                          " (line " + std::to_string(points.node()->source().begin.line) +
                          "): a profile is either inline or from a CSV file; remove one");
      }
    }
    // A profile the mode does not follow would be ignored without a word (the load torque of a
    // speed-mode run is plant.load's, not a set-point).
    const bool speed_mode = out.scenario.mode == core::DriveMode::kSpeed;
    for (const char* key : speed_mode ? std::array{"operation.torque_Nm", "operation.torque_csv"}
                                      : std::array{"operation.speed_rad_s", "operation.speed_csv"}) {
      if (const auto node = root.at_path(key)) {
        throw ConfigError(where(*node.node(), source.string(), key) + "a set-point of " +
                          (speed_mode ? "torque" : "speed") + " mode, but operation.mode is \"" +
                          (speed_mode ? "speed" : "torque") + "\"" +
                          (root.at_path("operation.mode") ? "" : " (the default)") + "; it would be ignored" +
                          (speed_mode ? " (the load's torque is [plant.load])" : " (the speed follows the load, [plant.load])") +
                          ": remove it or set the mode");
      }
    }
    const std::filesystem::path dir = source.parent_path();
    if (const auto node = root.at_path("operation.speed_rad_s")) {
      out.scenario.speed_rad_s = read_points(*node.node(), source.string(), "operation.speed_rad_s", kSpeedLimits);
    }
    auto csv_profile = [&](const char* key, Profile& into, const ProfileLimits& limits) {
      const auto node = root.at_path(key);
      if (!node) {
        return;
      }
      const std::string at = where(*node.node(), source.string(), key);
      const auto* text = node.as_string();
      if (text == nullptr) {
        throw ConfigError(at + "expected a path (string)");
      }
      into = read_csv(dir / text->get(), key, at, limits);
      out.files.push_back(dir / text->get());
    };
    csv_profile("operation.speed_csv", out.scenario.speed_rad_s, kSpeedLimits);
    if (const auto node = root.at_path("operation.torque_Nm")) {
      out.scenario.torque_Nm = read_points(*node.node(), source.string(), "operation.torque_Nm", kTorqueLimits);
    }
    csv_profile("operation.torque_csv", out.scenario.torque_Nm, kTorqueLimits);
    if (speed_mode && out.scenario.speed_rad_s.empty()) {
      throw ConfigError(source.string() + ": operation.speed_rad_s (or operation.speed_csv) is required in speed mode");
    }
    if (!speed_mode && out.scenario.torque_Nm.empty()) {
      throw ConfigError(source.string() + ": operation.torque_Nm (or operation.torque_csv) is required in torque mode");
    }
  }));
  // The seed and the ambient profile need the scenario's keys alone. (A seed the plant's own
  // plant.simulation.seed overrides is not used, and not judged.)
  if (scenario_ok) {
    (void)attempt([&] {
      if (const auto node = root.at_path("scenario.seed"); node && !root.at_path("plant.simulation.seed")) {
        if (const auto* seed = node.as_integer(); seed == nullptr || seed->get() < 0) {
          throw ConfigError(where(*node.node(), source.string(), "scenario.seed") + "expected an integer >= 0");
        }
      }
    });
    (void)attempt([&] {
      // The ambient profile is a flat list t0, C0, t1, C1, ... with ascending times.
      if (const auto node = root.at_path("scenario.ambient_profile")) {
        const std::string at = where(*node.node(), source.string(), "scenario.ambient_profile");
        const auto& points = out.scenario.ambient_profile.points;
        if (node.as_array() != nullptr && node.as_array()->size() % 2 != 0) {
          throw ConfigError(at + "expected pairs of time_s and temperature_C (an even number of values)");
        }
        for (std::size_t k = 1; k < points.size(); ++k) {
          if (!(points[k].time_s > points[k - 1].time_s)) {
            throw ConfigError(at + "times must ascend");
          }
        }
        for (const ProfilePoint& q : points) {  // the bounds of scenario.ambient_C
          if (!(q.time_s >= 0.0 && q.time_s <= kMaxProfileTime_s) || !(q.value >= -40.0 && q.value <= 80.0)) {
            throw ConfigError(at + "every point needs time_s >= 0 and a temperature in [-40, 80] C, got " +
                              common::format_number(q.time_s) + ", " + common::format_number(q.value));
          }
        }
      }
    });
  }
  (void)attempt([&] {
    out.plant = load_plant(root, source, out.files);
    if (!out.plant.load.csv_path.empty()) {
      out.files.push_back(out.plant.load.csv_path);
    }
  });
  bool controller_ok = false;
  (void)attempt([&] {
    // The controller: the same sections as pmsm-thermald's configuration, under [controller]
    // (parsed in place, so that messages keep the file's line numbers).
    static const toml::table kEmpty;
    const toml::table* controller_table = common::optional_section(root, "controller", source.string());
    out.controller = parse_controller_config(controller_table != nullptr ? *controller_table : kEmpty, source.string(), {},
                                             "controller.");
    for (const std::string& file : {out.controller.calibration_file, out.controller.thermal_state_file}) {
      if (!file.empty()) {
        out.files.emplace_back(file);
      }
    }
    controller_ok = true;
  });
  // The supervisor's keys (its defaults follow the drive's, as pmsm-thermald's do), and every rule
  // between them and the drive's, worded as the daemon words them.
  (void)attempt([&] {
    out.supervisor = parse_scenario_supervisor(root, source.string(), default_supervisor_config(out.controller));
    common::KeyRules broken(root, source.string());
    broken.append(check_supervisor_own_rules(out.supervisor, root, source.string()));
    if (controller_ok) {
      broken.append(check_supervisor_rules(out.supervisor, out.controller, root, source.string()));
    }
    if (broken.any()) {
      throw ConfigError(broken.errors());
    }
  });
  if (!errors.empty()) {
    throw ConfigError(errors);
  }
  // The scenario's ambient, seed and acceleration apply to the plant unless it says otherwise
  // (every part read cleanly: the seed is an integer >= 0).
  if (!root.at_path("plant.thermal.ambient_C")) {
    out.plant.thermal.ambient_C = out.scenario.ambient_profile.empty() ? out.scenario.ambient_C
                                                                        : out.scenario.ambient_profile.at(0.0);
  }
  if (root.at_path("scenario.thermal_acceleration") && !root.at_path("plant.thermal.acceleration")) {
    out.plant.thermal.acceleration = out.scenario.thermal_acceleration;
  }
  if (const auto node = root.at_path("scenario.seed"); node && !root.at_path("plant.simulation.seed")) {
    out.plant.simulation.seed = static_cast<std::uint64_t>(node.as_integer()->get());
  }
  // The scenario's acceleration applies to the controller's thermal model too, unless the
  // controller section sets its own.
  if (root.at_path("scenario.thermal_acceleration") && !root.at_path("controller.thermal.acceleration")) {
    out.controller.drive.thermal.time_scale = out.scenario.thermal_acceleration;
    // The controller's check of thermal.update_s against its model's time constant saw its own
    // acceleration (1): the scenario's is judged here.
    const double tau_s = core::thermal_model_fastest_time_constant_s(out.controller.drive.thermal);
    const double step_s = out.controller.drive.thermal_update_s * out.scenario.thermal_acceleration;
    if (!(step_s <= core::kMaxThermalStepPerTimeConstant * tau_s)) {
      throw ConfigError(where(*root.at_path("scenario.thermal_acceleration").node(), source.string(),
                              "scenario.thermal_acceleration") +
                        common::format_number(out.scenario.thermal_acceleration) + " times controller.thermal.update_s (" +
                        common::format_number(out.controller.drive.thermal_update_s) + " s) is " +
                        common::format_number(step_s) + " s of thermal time per update of the drive's thermal filter, more than " +
                        common::format_number(core::kMaxThermalStepPerTimeConstant) +
                        " of its model's fastest time constant, " + common::format_number(tau_s) +
                        " s: its prediction would be wrong, and beyond twice it diverge; lower the acceleration or "
                        "controller.thermal.update_s");
    }
  }
  // A calibration asked for at or after the run's end never runs: the run's figures would count
  // from a calibration that is not there, and say nothing.
  if (out.scenario.calibrate && out.scenario.calibrate_at_s >= out.scenario.duration_s) {
    const auto at_key = root.at_path("operation.calibrate_at_s");
    const char* key = at_key ? "operation.calibrate_at_s" : "scenario.duration_s";
    const auto node = at_key ? at_key : root.at_path("scenario.duration_s");
    const std::string at = node ? where(*node.node(), source.string(), key) : source.string() + ": " + key + ": ";
    throw ConfigError(at + "the calibration starts at operation.calibrate_at_s = " +
                      common::format_number(out.scenario.calibrate_at_s) + " s, not before the run ends at scenario.duration_s = " +
                      common::format_number(out.scenario.duration_s) +
                      " s: start it earlier, run longer, or set operation.calibrate = false");
  }
  // The error figures and the time series are sampled every log period: one longer than the run
  // samples nothing, and the report said "no samples above the threshold" of a run that heated.
  if (out.scenario.log_period_s > out.scenario.duration_s) {
    const auto given = root.at_path("metrics.log_period_s");
    const std::string at = given ? where(*given.node(), source.string(), "metrics.log_period_s")
                                 : source.string() + ": metrics.log_period_s: ";
    throw ConfigError(at + common::format_number(out.scenario.log_period_s) + " s is longer than the run, scenario.duration_s = " +
                      common::format_number(out.scenario.duration_s) + " s: the figures would sample nothing");
  }
  // The drive steps once per plant sample, so its period is the plant's PWM period: a
  // mismatch would run every clock of the drive (its timers, the speed from the angle's
  // advance, the thermal model, an estimate's age) at the wrong rate without a word.
  const double plant_period_s = 1.0 / out.plant.inverter.pwm_frequency_Hz;
  const double period_s = out.controller.drive.period_s;
  // Within a millionth (a period typed to seven digits, 8.333333e-5 for 12 kHz: 3.6 ms an hour
  // on the drive's clocks); the message prints ten digits, where six made 8.33333e-05 read the
  // same as what was refused.
  if (!(std::abs(period_s - plant_period_s) <= 1e-6 * plant_period_s)) {
    const auto given = root.at_path("controller.control.period_s");
    const std::string at = given ? where(*given.node(), source.string(), "controller.control.period_s")
                                 : source.string() + ": controller.control.period_s: ";
    throw ConfigError(at + "must be the plant's PWM period, 1 / plant.inverter.pwm_frequency_Hz = " +
                      fmt::format("{:.10g}", plant_period_s) + " s (the drive steps once per plant sample), got " +
                      fmt::format("{:.10g}", period_s) + " s");
  }
  return out;
}

Scenario load_scenario(const std::filesystem::path& path) {
  return parse_scenario(common::read_config_file(path, "scenario"), path);
}

std::string scenario_keys_markdown() {
  // The scenario's own keys, then [supervisor]'s (the daemon's, read by its code), in one table:
  // their defaults are the daemon's for the default drive (a scenario's drive takes them for its
  // own motor and bus).
  return schema().markdown(ScenarioConfig{}) +
         scenario_supervisor_keys_markdown(default_supervisor_config(default_controller_config()));
}

}  // namespace pmsm::app
