// TOML configuration of the plant. One table (fields()) describes every key once: its
// place in PlantConfig, type, range, unit and meaning. Parsing, range checks, the unknown-key
// check and the Markdown reference in docs/plant.md are all driven by it.
#include "pmsm/plant/config.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include <fmt/format.h>
#include <toml++/toml.h>

namespace pmsm::plant {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

enum class Kind { real, integer, boolean, choice, real3, points, int_list, real_list, path,
                  optional_real, seed };

// A closed or open numeric interval; infinite ends mean "no bound".
struct Range {
  double lo = -kInf;
  double hi = kInf;
  bool lo_open = false;
  bool hi_open = false;

  [[nodiscard]] bool contains(double v) const {
    const bool above = lo_open ? v > lo : v >= lo;
    const bool below = hi_open ? v < hi : v <= hi;
    return above && below;
  }
  [[nodiscard]] std::string describe() const {
    const bool has_lo = std::isfinite(lo);
    const bool has_hi = std::isfinite(hi);
    if (has_lo && has_hi) {
      return fmt::format("in {}{}, {}{}", lo_open ? "(" : "[", lo, hi, hi_open ? ")" : "]");
    }
    if (has_lo) {
      return fmt::format("{} {}", lo_open ? ">" : ">=", lo);
    }
    if (has_hi) {
      return fmt::format("{} {}", hi_open ? "<" : "<=", hi);
    }
    return "any";
  }
};

constexpr Range any() { return {}; }
constexpr Range positive(double hi = kInf) { return {0.0, hi, true, false}; }
constexpr Range non_negative(double hi = kInf) { return {0.0, hi, false, false}; }
constexpr Range closed(double lo, double hi) { return {lo, hi, false, false}; }

struct Choice {
  std::string_view name;
  int value;
};

struct Field {
  std::string_view key;
  Kind kind;
  Range range;
  std::string_view doc;
  double& (*real)(PlantConfig&) = nullptr;
  int& (*integer)(PlantConfig&) = nullptr;
  bool& (*boolean)(PlantConfig&) = nullptr;
  std::array<double, 3>& (*real3)(PlantConfig&) = nullptr;
  std::vector<TimePoint>& (*points)(PlantConfig&) = nullptr;
  std::vector<int>& (*int_list)(PlantConfig&) = nullptr;
  std::vector<double>& (*real_list)(PlantConfig&) = nullptr;
  std::filesystem::path& (*path)(PlantConfig&) = nullptr;
  std::optional<double>& (*optional_real)(PlantConfig&) = nullptr;
  std::uint64_t& (*seed)(PlantConfig&) = nullptr;
  // Choices map names to enum values through these two.
  int (*get_choice)(const PlantConfig&) = nullptr;
  void (*set_choice)(PlantConfig&, int) = nullptr;
  std::vector<Choice> choices{};
};

// Accessor for one member of PlantConfig; a captureless lambda becomes a function pointer.
#define PMSM_MEMBER(member) [](PlantConfig& c) -> auto& { return c.member; }

Field real(std::string_view key, double& (*acc)(PlantConfig&), Range r, std::string_view doc) {
  return Field{.key = key, .kind = Kind::real, .range = r, .doc = doc, .real = acc};
}
Field integer(std::string_view key, int& (*acc)(PlantConfig&), Range r, std::string_view doc) {
  return Field{.key = key, .kind = Kind::integer, .range = r, .doc = doc, .integer = acc};
}
Field boolean(std::string_view key, bool& (*acc)(PlantConfig&), std::string_view doc) {
  return Field{.key = key, .kind = Kind::boolean, .range = any(), .doc = doc, .boolean = acc};
}
Field real3(std::string_view key, std::array<double, 3>& (*acc)(PlantConfig&), Range r,
            std::string_view doc) {
  return Field{.key = key, .kind = Kind::real3, .range = r, .doc = doc, .real3 = acc};
}

const std::vector<Field>& fields() {
  static const std::vector<Field> table = [] {
    std::vector<Field> f;
    // [simulation]
    f.push_back(Field{.key = "simulation.seed", .kind = Kind::seed, .range = non_negative(),
                      .doc = "Seed of the sensor-noise generator (std::mt19937_64). The same "
                             "seed gives a bit-identical sample stream.",
                      .seed = PMSM_MEMBER(simulation.seed)});
    f.push_back(integer("simulation.substeps", PMSM_MEMBER(simulation.substeps), closed(1, 64),
                        "RK4 integration steps per PWM period."));
    // [motor]
    f.push_back(integer("motor.pole_pairs", PMSM_MEMBER(motor.pole_pairs), closed(1, 64),
                        "Pole pairs p (Table I: 3)."));
    f.push_back(real("motor.Rs_ohm", PMSM_MEMBER(motor.Rs_ohm), positive(),
                     "Phase-to-neutral stator resistance Rs0 at Rs_ref_temp_C (Table I: "
                     "0.133 Ω at 25 °C)."));
    f.push_back(real("motor.Rs_ref_temp_C", PMSM_MEMBER(motor.Rs_ref_temp_C), closed(-50, 250),
                     "Temperature T0 at which Rs_ohm holds (Eq. 1)."));
    f.push_back(real("motor.alpha_per_C", PMSM_MEMBER(motor.alpha_per_C), closed(0, 0.01),
                     "Temperature coefficient of the winding resistance, Eq. 1 (copper: "
                     "3.93e-3 /°C)."));
    f.push_back(real("motor.Ke_V_s_rad", PMSM_MEMBER(motor.Ke_V_s_rad), positive(100.0),
                     "EMF constant of Table I: line-to-line RMS volts per mechanical rad/s, "
                     "at magnet_ref_temp_C. psi_m = Ke·sqrt(2/3)/p."));
    f.push_back(real("motor.Ld_H", PMSM_MEMBER(motor.Ld_H), positive(),
                     "d-axis inductance (default L_ll/2 of Table I)."));
    f.push_back(real("motor.Lq_H", PMSM_MEMBER(motor.Lq_H), positive(),
                     "q-axis inductance; Lq != Ld gives reluctance torque."));
    f.push_back(real("motor.magnet_temp_coeff_per_K", PMSM_MEMBER(motor.magnet_temp_coeff_per_K),
                     closed(-0.01, 0.0),
                     "Relative change of the magnet flux per kelvin (NdFeB about -0.12 %/K)."));
    f.push_back(real("motor.magnet_ref_temp_C", PMSM_MEMBER(motor.magnet_ref_temp_C),
                     closed(-50, 250), "Magnet temperature at which Ke_V_s_rad holds."));
    // [saturation]
    f.push_back(boolean("saturation.enabled", PMSM_MEMBER(saturation.enabled),
                        "Magnetic saturation of both axes (no cross-saturation)."));
    f.push_back(real("saturation.Ld_sat_H", PMSM_MEMBER(saturation.Ld_sat_H), positive(),
                     "Incremental d-axis inductance far beyond the knee (<= motor.Ld_H)."));
    f.push_back(real("saturation.Lq_sat_H", PMSM_MEMBER(saturation.Lq_sat_H), positive(),
                     "Incremental q-axis inductance far beyond the knee (<= motor.Lq_H)."));
    f.push_back(real("saturation.id_knee_A", PMSM_MEMBER(saturation.id_knee_A), positive(1e4),
                     "d-axis current at the knee of the saturation curve."));
    f.push_back(real("saturation.iq_knee_A", PMSM_MEMBER(saturation.iq_knee_A), positive(1e4),
                     "q-axis current at the knee of the saturation curve."));
    // [emf]
    f.push_back(Field{
        .key = "emf.shape", .kind = Kind::choice, .range = any(),
        .doc = "Back-EMF waveform (Fig. 11): sinusoidal 100 %, modular 89 %, trapezoidal 77 % "
               "fundamental (fundamental / peak, fundamental fixed by Ke), or custom.",
        .get_choice = [](const PlantConfig& c) { return static_cast<int>(c.emf.shape); },
        .set_choice = [](PlantConfig& c, int v) { c.emf.shape = static_cast<EmfShape>(v); },
        .choices = {{"sinusoidal", static_cast<int>(EmfShape::sinusoidal)},
                    {"modular", static_cast<int>(EmfShape::modular)},
                    {"trapezoidal", static_cast<int>(EmfShape::trapezoidal)},
                    {"custom", static_cast<int>(EmfShape::custom)}}});
    f.push_back(Field{.key = "emf.harmonic_orders", .kind = Kind::int_list, .range = closed(5, 99),
                      .doc = "shape = \"custom\": harmonic orders n (odd, not multiples of 3, "
                             "at most 12).",
                      .int_list = PMSM_MEMBER(emf.custom_orders)});
    f.push_back(Field{.key = "emf.harmonic_amplitudes", .kind = Kind::real_list,
                      .range = closed(-1, 1),
                      .doc = "shape = \"custom\": b_n relative to the fundamental, phase EMF "
                             "-(sin θ + Σ b_n sin nθ)·ω_e·psi_m.",
                      .real_list = PMSM_MEMBER(emf.custom_amplitudes)});
    // [cogging]
    f.push_back(boolean("cogging.enabled", PMSM_MEMBER(cogging.enabled),
                        "Cogging torque amplitude·sin(order·θ_m + phase)."));
    f.push_back(real("cogging.amplitude_Nm", PMSM_MEMBER(cogging.amplitude_Nm),
                     non_negative(100.0), "Cogging torque amplitude."));
    f.push_back(integer("cogging.order", PMSM_MEMBER(cogging.order), closed(1, 1000),
                        "Cogging cycles per mechanical revolution."));
    f.push_back(real("cogging.phase_rad", PMSM_MEMBER(cogging.phase_rad), any(),
                     "Cogging phase."));
    // [mechanics]
    f.push_back(real("mechanics.J_kg_m2", PMSM_MEMBER(mechanics.J_kg_m2), positive(1e3),
                     "Total inertia on the shaft (Table I rotor: 0.00841)."));
    f.push_back(real("mechanics.coulomb_Nm", PMSM_MEMBER(mechanics.coulomb_Nm),
                     non_negative(1e3), "Kinetic Coulomb friction (Table I: 0.908)."));
    f.push_back(real("mechanics.breakaway_Nm", PMSM_MEMBER(mechanics.breakaway_Nm),
                     non_negative(1e3),
                     "Static friction: a stopped shaft stays stuck while the net driving "
                     "torque is below it (>= coulomb_Nm)."));
    f.push_back(real("mechanics.viscous_Nm_s_rad", PMSM_MEMBER(mechanics.viscous_Nm_s_rad),
                     non_negative(10.0), "Viscous friction coefficient."));
    f.push_back(real("mechanics.initial_speed_rad_s", PMSM_MEMBER(mechanics.initial_speed_rad_s),
                     closed(-2000, 2000), "Mechanical speed at t = 0."));
    f.push_back(real("mechanics.initial_angle_rad", PMSM_MEMBER(mechanics.initial_angle_rad),
                     any(), "Mechanical angle of the rotor d-axis from phase a at t = 0."));
    // [load]
    f.push_back(Field{
        .key = "load.profile", .kind = Kind::choice, .range = any(),
        .doc = "constant: torque_Nm. steps: torque_Nm, then the steps table. fan: torque_Nm + "
               "fan_k_Nm_s2·ω·|ω|. csv: drive cycle file (torque_Nm column: load torque; "
               "speed_rad_s column: imposed speed). speed: dynamometer imposing speed_rad_s "
               "or the speed_points table.",
        .get_choice = [](const PlantConfig& c) { return static_cast<int>(c.load.profile); },
        .set_choice = [](PlantConfig& c, int v) { c.load.profile = static_cast<LoadProfile>(v); },
        .choices = {{"constant", static_cast<int>(LoadProfile::constant_torque)},
                    {"steps", static_cast<int>(LoadProfile::torque_steps)},
                    {"fan", static_cast<int>(LoadProfile::fan)},
                    {"csv", static_cast<int>(LoadProfile::torque_cycle)},
                    {"speed", static_cast<int>(LoadProfile::speed_cycle)}}});
    f.push_back(real("load.torque_Nm", PMSM_MEMBER(load.torque_Nm), closed(-1e4, 1e4),
                     "Constant load torque (positive opposes positive rotation); the initial "
                     "value for steps, the offset for fan."));
    f.push_back(Field{.key = "load.steps", .kind = Kind::points, .range = closed(-1e4, 1e4),
                      .doc = "profile = \"steps\": [[time_s, torque_Nm], ...], times ascending; "
                             "each torque holds from its time on.",
                      .points = PMSM_MEMBER(load.points)});
    f.push_back(real("load.fan_k_Nm_s2", PMSM_MEMBER(load.fan_k_Nm_s2), closed(-10, 10),
                     "profile = \"fan\": k of T = k·ω·|ω| (fan or pump)."));
    f.push_back(Field{.key = "load.csv_path", .kind = Kind::path, .range = any(),
                      .doc = "profile = \"csv\": drive cycle with a header: time_s and either "
                             "speed_rad_s or torque_Nm; linear interpolation, ends held. "
                             "Relative to the TOML file.",
                      .path = PMSM_MEMBER(load.csv_path)});
    f.push_back(real("load.speed_rad_s", PMSM_MEMBER(load.speed_rad_s), closed(-2000, 2000),
                     "profile = \"speed\" without speed_points: constant imposed speed."));
    f.push_back(Field{.key = "load.speed_points", .kind = Kind::points,
                      .range = closed(-2000, 2000),
                      .doc = "profile = \"speed\": [[time_s, speed_rad_s], ...], linear "
                             "interpolation (repeat a time for a step), ends held.",
                      .points = PMSM_MEMBER(load.points)});
    f.push_back(real("load.dyno_bandwidth_Hz", PMSM_MEMBER(load.dyno_bandwidth_Hz),
                     non_negative(1000.0),
                     "Imposed speed: 0 = ideal dynamometer (speed exact); > 0 = PI speed "
                     "loop of this bandwidth acting through the load torque."));
    f.push_back(boolean("load.ripple_enabled", PMSM_MEMBER(load.ripple_enabled),
                        "Load-torque ripple T·(1 + fraction·sin(order·θ_m + phase))."));
    f.push_back(real("load.ripple_fraction", PMSM_MEMBER(load.ripple_fraction), closed(0, 1),
                     "Ripple amplitude relative to the load torque (reference: 2 %)."));
    f.push_back(real("load.ripple_order", PMSM_MEMBER(load.ripple_order), positive(1000.0),
                     "Ripple cycles per mechanical revolution."));
    f.push_back(real("load.ripple_phase_rad", PMSM_MEMBER(load.ripple_phase_rad), any(),
                     "Ripple phase."));
    // [inverter]
    f.push_back(real("inverter.pwm_frequency_Hz", PMSM_MEMBER(inverter.pwm_frequency_Hz),
                     closed(1000, 100000), "PWM, sampling and control frequency fs."));
    f.push_back(real("inverter.dc_bus_V", PMSM_MEMBER(inverter.dc_bus_V), positive(2000.0),
                     "Nominal DC-bus voltage."));
    f.push_back(boolean("inverter.dc_ripple_enabled", PMSM_MEMBER(inverter.dc_ripple_enabled),
                        "DC-bus ripple Vdc·(1 + fraction·sin(2π·f·t))."));
    f.push_back(real("inverter.dc_ripple_fraction", PMSM_MEMBER(inverter.dc_ripple_fraction),
                     closed(0, 0.5), "DC-bus ripple amplitude (peak) relative to dc_bus_V."));
    f.push_back(real("inverter.dc_ripple_frequency_Hz",
                     PMSM_MEMBER(inverter.dc_ripple_frequency_Hz), positive(1e5),
                     "DC-bus ripple frequency (six-pulse rectifier on 50 Hz: 300 Hz)."));
    f.push_back(boolean("inverter.dead_time_enabled", PMSM_MEMBER(inverter.dead_time_enabled),
                        "Dead-time voltage error (not compensated by the plant)."));
    f.push_back(real("inverter.dead_time_s", PMSM_MEMBER(inverter.dead_time_s),
                     non_negative(1e-4), "Dead time Td per switching edge pair."));
    f.push_back(boolean("inverter.device_drop_enabled",
                        PMSM_MEMBER(inverter.device_drop_enabled),
                        "Forward drop of the conducting switch or diode."));
    f.push_back(real("inverter.device_drop_V", PMSM_MEMBER(inverter.device_drop_V),
                     non_negative(20.0), "Device forward drop, opposing the phase current."));
    f.push_back(real("inverter.zero_current_band_A", PMSM_MEMBER(inverter.zero_current_band_A),
                     positive(100.0),
                     "Half the peak-to-peak PWM ripple: below it the dead-time and drop "
                     "errors fall linearly to zero with the current."));
    f.push_back(integer("inverter.computation_delay_periods",
                        PMSM_MEMBER(inverter.computation_delay_periods), closed(0, 1),
                        "1: a command computed from sample k acts in period k+1 (a real "
                        "drive); 0: in period k (debugging only)."));
    f.push_back(boolean("inverter.overcurrent_trip_enabled",
                        PMSM_MEMBER(inverter.overcurrent_trip_enabled),
                        "Hardware over-current comparator: turns the gates off, latched until "
                        "a command with enable = false."));
    f.push_back(real("inverter.overcurrent_trip_A", PMSM_MEMBER(inverter.overcurrent_trip_A),
                     positive(1e4), "Trip level on any phase current at a sample instant."));
    // [current_adc]
    f.push_back(integer("current_adc.bits", PMSM_MEMBER(current_adc.bits), closed(2, 16),
                        "Phase-current ADC resolution; codes are signed, LSB = "
                        "range_A / 2^(bits-1)."));
    f.push_back(real("current_adc.range_A", PMSM_MEMBER(current_adc.range_A), positive(1e4),
                     "Full scale ±range_A."));
    f.push_back(boolean("current_adc.noise_enabled", PMSM_MEMBER(current_adc.noise_enabled),
                        "Gaussian noise on each phase current."));
    f.push_back(real("current_adc.noise_A", PMSM_MEMBER(current_adc.noise_A), non_negative(100.0),
                     "Noise standard deviation."));
    f.push_back(boolean("current_adc.offset_enabled", PMSM_MEMBER(current_adc.offset_enabled),
                        "Per-phase offset."));
    f.push_back(real3("current_adc.offset_A", PMSM_MEMBER(current_adc.offset_A),
                      closed(-100, 100), "Offsets of phases a, b, c."));
    f.push_back(boolean("current_adc.gain_error_enabled",
                        PMSM_MEMBER(current_adc.gain_error_enabled), "Per-phase gain error."));
    f.push_back(real3("current_adc.gain_error", PMSM_MEMBER(current_adc.gain_error),
                      closed(-0.5, 0.5),
                      "Relative gain errors of phases a, b, c (measured = (1 + e)·true)."));
    // [encoder]
    f.push_back(integer("encoder.bits", PMSM_MEMBER(encoder.bits), closed(1, 16),
                        "Absolute encoder resolution: counts 0 .. 2^bits - 1 per mechanical "
                        "revolution."));
    f.push_back(real("encoder.offset_rad", PMSM_MEMBER(encoder.offset_rad), any(),
                     "Mechanical angle read as count 0."));
    // [dc_bus_adc]
    f.push_back(integer("dc_bus_adc.bits", PMSM_MEMBER(dc_bus_adc.bits), closed(2, 16),
                        "DC-bus ADC resolution; unsigned codes, LSB = full_scale_V / 2^bits."));
    f.push_back(real("dc_bus_adc.full_scale_V", PMSM_MEMBER(dc_bus_adc.full_scale_V),
                     positive(1e4), "DC-bus ADC full scale."));
    f.push_back(boolean("dc_bus_adc.noise_enabled", PMSM_MEMBER(dc_bus_adc.noise_enabled),
                        "Gaussian noise on the DC-bus measurement."));
    f.push_back(real("dc_bus_adc.noise_V", PMSM_MEMBER(dc_bus_adc.noise_V), non_negative(100.0),
                     "Noise standard deviation."));
    // [phase_voltage_sensing]
    f.push_back(boolean("phase_voltage_sensing.enabled",
                        PMSM_MEMBER(phase_voltage_sensing.enabled),
                        "Measure the phase-to-neutral voltages (mean over the last period) "
                        "and set kSensorPhaseVoltageValid."));
    f.push_back(integer("phase_voltage_sensing.bits", PMSM_MEMBER(phase_voltage_sensing.bits),
                        closed(2, 16), "Signed codes, LSB = range_V / 2^(bits-1)."));
    f.push_back(real("phase_voltage_sensing.range_V", PMSM_MEMBER(phase_voltage_sensing.range_V),
                     positive(1e4), "Full scale ±range_V."));
    f.push_back(boolean("phase_voltage_sensing.noise_enabled",
                        PMSM_MEMBER(phase_voltage_sensing.noise_enabled),
                        "Gaussian noise on the phase voltages."));
    f.push_back(real("phase_voltage_sensing.noise_V", PMSM_MEMBER(phase_voltage_sensing.noise_V),
                     non_negative(100.0), "Noise standard deviation."));
    // [iron_loss]
    f.push_back(boolean("iron_loss.enabled", PMSM_MEMBER(iron_loss.enabled),
                        "Speed-dependent iron loss, taken from the shaft as a drag torque."));
    f.push_back(real("iron_loss.hysteresis_W_s_rad", PMSM_MEMBER(iron_loss.hysteresis_W_s_rad),
                     non_negative(100.0), "k_h of P = (k_h·|ω_e| + k_e·ω_e²)·(psi_m/psi_m0)²."));
    f.push_back(real("iron_loss.eddy_W_s2_rad2", PMSM_MEMBER(iron_loss.eddy_W_s2_rad2),
                     non_negative(1.0), "k_e of the iron-loss formula."));
    f.push_back(real("iron_loss.rotor_fraction", PMSM_MEMBER(iron_loss.rotor_fraction),
                     closed(0, 1), "Share of the iron loss heating the rotor node; the rest "
                                   "heats the stator iron/housing node."));
    // [thermal]
    f.push_back(boolean("thermal.enabled", PMSM_MEMBER(thermal.enabled),
                        "Thermal network; when false all temperatures stay at initial_C."));
    f.push_back(real("thermal.ambient_C", PMSM_MEMBER(thermal.ambient_C), closed(-50, 150),
                     "Ambient temperature (changeable at run time)."));
    f.push_back(Field{.key = "thermal.initial_C", .kind = Kind::optional_real,
                      .range = closed(-50, 250),
                      .doc = "Initial temperature of every node (default: ambient_C).",
                      .optional_real = PMSM_MEMBER(thermal.initial_C)});
    f.push_back(real("thermal.acceleration", PMSM_MEMBER(thermal.acceleration), closed(1e-3, 1e6),
                     "Thermal time runs this many times faster than electrical time."));
    f.push_back(real("thermal.C_winding_J_K", PMSM_MEMBER(thermal.C_winding_J_K), positive(1e7),
                     "Heat capacity of the winding node (copper and insulation)."));
    f.push_back(real("thermal.C_housing_J_K", PMSM_MEMBER(thermal.C_housing_J_K), positive(1e7),
                     "Heat capacity of the stator iron and housing node."));
    f.push_back(real("thermal.C_rotor_J_K", PMSM_MEMBER(thermal.C_rotor_J_K), positive(1e7),
                     "Heat capacity of the rotor (magnets, rotor iron, shaft) node."));
    f.push_back(real("thermal.R_winding_housing_K_W", PMSM_MEMBER(thermal.R_winding_housing_K_W),
                     positive(1e3), "Thermal resistance winding to housing."));
    f.push_back(real("thermal.R_housing_ambient_K_W", PMSM_MEMBER(thermal.R_housing_ambient_K_W),
                     positive(1e3), "Thermal resistance housing to ambient."));
    f.push_back(real("thermal.R_rotor_housing_K_W", PMSM_MEMBER(thermal.R_rotor_housing_K_W),
                     positive(1e3), "Thermal resistance rotor to housing (air gap, bearings)."));
    f.push_back(real("thermal.R_rotor_ambient_K_W", PMSM_MEMBER(thermal.R_rotor_ambient_K_W),
                     positive(1e6), "Thermal resistance rotor to ambient (shaft)."));
    f.push_back(real("thermal.friction_heat_fraction",
                     PMSM_MEMBER(thermal.friction_heat_fraction), closed(0, 1),
                     "Share of the friction loss heating the housing node."));
    return f;
  }();
  return table;
}

#undef PMSM_MEMBER

// The node at "section.key", or nullptr.
const toml::node* lookup(const toml::table& root, std::string_view key) {
  const auto dot = key.find('.');
  const toml::node* section = root.get(key.substr(0, dot));
  if (section == nullptr || !section->is_table()) {
    return nullptr;
  }
  return section->as_table()->get(key.substr(dot + 1));
}

const Field* find_field(std::string_view key) {
  for (const Field& f : fields()) {
    if (f.key == key) {
      return &f;
    }
  }
  return nullptr;
}

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) {
    row[j] = j;
  }
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      const std::size_t cost = (a[i - 1] == b[j - 1]) ? 0 : 1;
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + cost});
      diag = up;
    }
  }
  return row[b.size()];
}

// A hint for typos: the closest known key, if it is close enough to be the likely intent.
std::string suggestion(std::string_view key) {
  std::string_view best;
  std::size_t best_distance = std::numeric_limits<std::size_t>::max();
  for (const Field& f : fields()) {
    const std::size_t d = edit_distance(key, f.key);
    if (d < best_distance) {
      best_distance = d;
      best = f.key;
    }
  }
  if (best_distance <= 3) {
    return fmt::format(" (did you mean {}?)", best);
  }
  return {};
}

std::string type_name(const toml::node& node) {
  switch (node.type()) {
    case toml::node_type::string: return "a string";
    case toml::node_type::integer: return "an integer";
    case toml::node_type::floating_point: return "a floating-point number";
    case toml::node_type::boolean: return "a boolean";
    case toml::node_type::array: return "an array";
    case toml::node_type::table: return "a table";
    case toml::node_type::date: return "a date";
    case toml::node_type::time: return "a time";
    case toml::node_type::date_time: return "a date-time";
    case toml::node_type::none: break;
  }
  return "nothing";
}

// Raised while reading one key; the caller adds the source, line and key.
struct KeyError {
  std::string message;
};

double to_number(const toml::node& node) {
  if (const auto* i = node.as_integer()) {
    return static_cast<double>(i->get());
  }
  if (const auto* d = node.as_floating_point()) {
    if (!std::isfinite(d->get())) {
      throw KeyError{fmt::format("must be a finite number, got {}", d->get())};
    }
    return d->get();
  }
  throw KeyError{fmt::format("expected a number, got {}", type_name(node))};
}

void check_range(const Range& r, double v) {
  if (!r.contains(v)) {
    throw KeyError{fmt::format("must be {}, got {}", r.describe(), v)};
  }
}

std::int64_t to_integer(const toml::node& node) {
  if (const auto* i = node.as_integer()) {
    return i->get();
  }
  throw KeyError{fmt::format("expected an integer, got {}", type_name(node))};
}

void read_field(const Field& f, const toml::node& node, PlantConfig& c) {
  switch (f.kind) {
    case Kind::real: {
      const double v = to_number(node);
      check_range(f.range, v);
      f.real(c) = v;
      return;
    }
    case Kind::optional_real: {
      const double v = to_number(node);
      check_range(f.range, v);
      f.optional_real(c) = v;
      return;
    }
    case Kind::integer: {
      const std::int64_t v = to_integer(node);
      check_range(f.range, static_cast<double>(v));
      f.integer(c) = static_cast<int>(v);
      return;
    }
    case Kind::seed: {
      const std::int64_t v = to_integer(node);
      check_range(f.range, static_cast<double>(v));
      f.seed(c) = static_cast<std::uint64_t>(v);
      return;
    }
    case Kind::boolean: {
      const auto* b = node.as_boolean();
      if (b == nullptr) {
        throw KeyError{fmt::format("expected true or false, got {}", type_name(node))};
      }
      f.boolean(c) = b->get();
      return;
    }
    case Kind::choice: {
      const auto* s = node.as_string();
      std::string names;
      for (const Choice& ch : f.choices) {
        names += fmt::format("{}\"{}\"", names.empty() ? "" : ", ", ch.name);
      }
      if (s == nullptr) {
        throw KeyError{fmt::format("expected one of {}, got {}", names, type_name(node))};
      }
      for (const Choice& ch : f.choices) {
        if (ch.name == s->get()) {
          f.set_choice(c, ch.value);
          return;
        }
      }
      throw KeyError{fmt::format("must be one of {}, got \"{}\"", names, s->get())};
    }
    case Kind::path: {
      const auto* s = node.as_string();
      if (s == nullptr) {
        throw KeyError{fmt::format("expected a file path string, got {}", type_name(node))};
      }
      f.path(c) = std::filesystem::path(s->get());
      return;
    }
    case Kind::real3: {
      const auto* a = node.as_array();
      if (a == nullptr || a->size() != 3) {
        throw KeyError{fmt::format("expected an array of 3 numbers (phases a, b, c), got {}",
                                   a == nullptr ? type_name(node)
                                                : fmt::format("{} elements", a->size()))};
      }
      std::array<double, 3> v{};
      for (std::size_t i = 0; i < 3; ++i) {
        v[i] = to_number(*a->get(i));
        check_range(f.range, v[i]);
      }
      f.real3(c) = v;
      return;
    }
    case Kind::int_list: {
      const auto* a = node.as_array();
      if (a == nullptr) {
        throw KeyError{fmt::format("expected an array of integers, got {}", type_name(node))};
      }
      std::vector<int> v;
      for (const toml::node& e : *a) {
        const std::int64_t x = to_integer(e);
        check_range(f.range, static_cast<double>(x));
        v.push_back(static_cast<int>(x));
      }
      f.int_list(c) = std::move(v);
      return;
    }
    case Kind::real_list: {
      const auto* a = node.as_array();
      if (a == nullptr) {
        throw KeyError{fmt::format("expected an array of numbers, got {}", type_name(node))};
      }
      std::vector<double> v;
      for (const toml::node& e : *a) {
        const double x = to_number(e);
        check_range(f.range, x);
        v.push_back(x);
      }
      f.real_list(c) = std::move(v);
      return;
    }
    case Kind::points: {
      const auto* a = node.as_array();
      if (a == nullptr) {
        throw KeyError{fmt::format("expected an array of [time_s, value] pairs, got {}",
                                   type_name(node))};
      }
      std::vector<TimePoint> v;
      for (std::size_t i = 0; i < a->size(); ++i) {
        const auto* pair = a->get(i)->as_array();
        if (pair == nullptr || pair->size() != 2) {
          throw KeyError{fmt::format("element {}: expected [time_s, value]", i)};
        }
        TimePoint p{to_number(*pair->get(0)), to_number(*pair->get(1))};
        if (p.time_s < 0.0) {
          throw KeyError{fmt::format("element {}: time must be >= 0, got {}", i, p.time_s)};
        }
        if (!v.empty() && p.time_s < v.back().time_s) {
          throw KeyError{fmt::format("element {}: times must be ascending, got {} after {}", i,
                                     p.time_s, v.back().time_s)};
        }
        if (!f.range.contains(p.value)) {
          throw KeyError{fmt::format("element {}: value must be {}, got {}", i,
                                     f.range.describe(), p.value)};
        }
        v.push_back(p);
      }
      f.points(c) = std::move(v);
      return;
    }
  }
}

std::string format_default(const Field& f, PlantConfig& c) {
  switch (f.kind) {
    case Kind::real: return fmt::format("{}", f.real(c));
    case Kind::integer: return fmt::format("{}", f.integer(c));
    case Kind::seed: return fmt::format("{}", f.seed(c));
    case Kind::boolean: return f.boolean(c) ? "true" : "false";
    case Kind::optional_real: {
      const auto& v = f.optional_real(c);
      return v ? fmt::format("{}", *v) : std::string("ambient_C");
    }
    case Kind::choice: {
      const int v = f.get_choice(c);
      for (const Choice& ch : f.choices) {
        if (ch.value == v) {
          return fmt::format("\"{}\"", ch.name);
        }
      }
      return "?";
    }
    case Kind::path: return "\"\"";
    case Kind::real3: {
      const auto& v = f.real3(c);
      return fmt::format("[{}, {}, {}]", v[0], v[1], v[2]);
    }
    case Kind::int_list:
    case Kind::real_list:
    case Kind::points: return "[]";
  }
  return "?";
}

std::string_view kind_name(Kind k) {
  switch (k) {
    case Kind::real: return "number";
    case Kind::integer: return "integer";
    case Kind::seed: return "integer";
    case Kind::boolean: return "bool";
    case Kind::choice: return "string";
    case Kind::real3: return "3 numbers";
    case Kind::points: return "[[t, v], ...]";
    case Kind::int_list: return "integers";
    case Kind::real_list: return "numbers";
    case Kind::path: return "string";
    case Kind::optional_real: return "number";
  }
  return "?";
}

std::string trim(std::string_view s) {
  const auto first = s.find_first_not_of(" \t\r\n");
  if (first == std::string_view::npos) {
    return {};
  }
  const auto last = s.find_last_not_of(" \t\r\n");
  return std::string(s.substr(first, last - first + 1));
}

std::vector<std::string> split_csv(std::string_view line) {
  std::vector<std::string> out;
  std::size_t start = 0;
  while (true) {
    const auto comma = line.find(',', start);
    out.push_back(trim(line.substr(start, comma == std::string_view::npos ? line.size() - start
                                                                          : comma - start)));
    if (comma == std::string_view::npos) {
      break;
    }
    start = comma + 1;
  }
  return out;
}

}  // namespace

double psi_m_from_Ke(double Ke_V_s_rad, int pole_pairs) {
  // Ke: line-to-line RMS volts per mechanical rad/s. Phase peak per mechanical rad/s is
  // Ke·sqrt(2)/sqrt(3); per electrical rad/s divide by p.
  return Ke_V_s_rad * std::sqrt(2.0 / 3.0) / static_cast<double>(pole_pairs);
}

std::string_view to_string(EmfShape shape) {
  switch (shape) {
    case EmfShape::sinusoidal: return "sinusoidal";
    case EmfShape::modular: return "modular";
    case EmfShape::trapezoidal: return "trapezoidal";
    case EmfShape::custom: return "custom";
  }
  return "?";
}

std::string_view to_string(LoadProfile profile) {
  switch (profile) {
    case LoadProfile::constant_torque: return "constant";
    case LoadProfile::torque_steps: return "steps";
    case LoadProfile::fan: return "fan";
    case LoadProfile::torque_cycle: return "csv (torque)";
    case LoadProfile::speed_cycle: return "speed";
  }
  return "?";
}

void load_drive_cycle_csv(const std::filesystem::path& path, LoadConfig& load,
                          std::string_view key) {
  std::ifstream in(path);
  if (!in) {
    throw ConfigError(fmt::format("{}: cannot open drive cycle \"{}\"", key, path.string()));
  }
  const std::string where = fmt::format("{}: {}", key, path.string());
  std::string line;
  std::size_t line_no = 0;
  std::size_t time_col = 0;
  std::size_t value_col = 0;
  std::size_t columns = 0;
  bool have_header = false;
  bool is_speed = false;
  std::vector<TimePoint> points;
  while (std::getline(in, line)) {
    ++line_no;
    const std::string t = trim(line);
    if (t.empty() || t.front() == '#') {
      continue;
    }
    const std::vector<std::string> cells = split_csv(t);
    if (!have_header) {
      std::optional<std::size_t> tc;
      std::optional<std::size_t> sc;
      std::optional<std::size_t> qc;
      for (std::size_t i = 0; i < cells.size(); ++i) {
        if (cells[i] == "time_s") tc = i;
        if (cells[i] == "speed_rad_s") sc = i;
        if (cells[i] == "torque_Nm") qc = i;
      }
      if (!tc || (sc.has_value() == qc.has_value())) {
        throw ConfigError(fmt::format(
            "{}:{}: the header must name time_s and exactly one of speed_rad_s, torque_Nm",
            where, line_no));
      }
      time_col = *tc;
      value_col = sc ? *sc : *qc;
      is_speed = sc.has_value();
      columns = cells.size();
      have_header = true;
      continue;
    }
    if (cells.size() != columns) {
      throw ConfigError(fmt::format("{}:{}: expected {} columns, got {}", where, line_no,
                                    columns, cells.size()));
    }
    auto number = [&](std::size_t col) {
      const std::string& cell = cells[col];
      double v = 0.0;
      const auto res = std::from_chars(cell.data(), cell.data() + cell.size(), v);
      if (res.ec != std::errc{} || res.ptr != cell.data() + cell.size() || !std::isfinite(v)) {
        throw ConfigError(fmt::format("{}:{}: column {}: not a number: \"{}\"", where, line_no,
                                      col + 1, cell));
      }
      return v;
    };
    const TimePoint p{number(time_col), number(value_col)};
    if (!points.empty() && p.time_s < points.back().time_s) {
      throw ConfigError(fmt::format("{}:{}: time_s must be ascending, got {} after {}", where,
                                    line_no, p.time_s, points.back().time_s));
    }
    points.push_back(p);
  }
  if (points.empty()) {
    throw ConfigError(fmt::format("{}: no data rows", where));
  }
  load.points = std::move(points);
  load.profile = is_speed ? LoadProfile::speed_cycle : LoadProfile::torque_cycle;
  load.csv_path = path;
}

void validate_plant_config(const PlantConfig& c) {
  auto fail = [](std::string_view key, const std::string& message) {
    throw ConfigError(fmt::format("{}: {}", key, message));
  };
  // The ranges of the key table hold for configs built in code too.
  PlantConfig copy = c;
  for (const Field& f : fields()) {
    auto check = [&](double v) {
      if (!f.range.contains(v) || !std::isfinite(v)) {
        fail(f.key, fmt::format("must be {}, got {}", f.range.describe(), v));
      }
    };
    switch (f.kind) {
      case Kind::real: check(f.real(copy)); break;
      case Kind::integer: check(f.integer(copy)); break;
      case Kind::optional_real:
        if (f.optional_real(copy)) {
          check(*f.optional_real(copy));
        }
        break;
      case Kind::real3:
        for (double v : f.real3(copy)) {
          check(v);
        }
        break;
      case Kind::seed:
      case Kind::boolean:
      case Kind::choice:
      case Kind::points:
      case Kind::int_list:
      case Kind::real_list:
      case Kind::path:
        break;
    }
  }
  if (c.saturation.enabled && c.saturation.Ld_sat_H > c.motor.Ld_H) {
    fail("saturation.Ld_sat_H", fmt::format("must be <= motor.Ld_H ({}), got {}", c.motor.Ld_H,
                                            c.saturation.Ld_sat_H));
  }
  if (c.saturation.enabled && c.saturation.Lq_sat_H > c.motor.Lq_H) {
    fail("saturation.Lq_sat_H", fmt::format("must be <= motor.Lq_H ({}), got {}", c.motor.Lq_H,
                                            c.saturation.Lq_sat_H));
  }
  if (c.mechanics.breakaway_Nm < c.mechanics.coulomb_Nm) {
    fail("mechanics.breakaway_Nm", fmt::format("must be >= mechanics.coulomb_Nm ({}), got {}",
                                               c.mechanics.coulomb_Nm, c.mechanics.breakaway_Nm));
  }
  if (c.emf.shape == EmfShape::custom) {
    if (c.emf.custom_orders.size() != c.emf.custom_amplitudes.size()) {
      fail("emf.harmonic_amplitudes",
           fmt::format("must have as many entries as emf.harmonic_orders ({}), got {}",
                       c.emf.custom_orders.size(), c.emf.custom_amplitudes.size()));
    }
    if (c.emf.custom_orders.size() > 12) {
      fail("emf.harmonic_orders",
           fmt::format("at most 12 harmonics, got {}", c.emf.custom_orders.size()));
    }
    for (int n : c.emf.custom_orders) {
      if (n < 5 || n % 2 == 0 || n % 3 == 0) {
        fail("emf.harmonic_orders",
             fmt::format("orders must be odd, >= 5 and not multiples of 3 (triplens are "
                         "zero-sequence and drive no current with an isolated neutral), got {}",
                         n));
      }
    }
  } else if (!c.emf.custom_orders.empty() || !c.emf.custom_amplitudes.empty()) {
    fail("emf.harmonic_orders", "only used with emf.shape = \"custom\"");
  }
  const double half_period_s = 0.5 / c.inverter.pwm_frequency_Hz;
  if (c.inverter.dead_time_s >= half_period_s) {
    fail("inverter.dead_time_s", fmt::format("must be < half a PWM period ({} s), got {}",
                                             half_period_s, c.inverter.dead_time_s));
  }
  for (std::size_t i = 1; i < c.load.points.size(); ++i) {
    if (c.load.points[i].time_s < c.load.points[i - 1].time_s) {
      fail("load.points", "times must be ascending");
    }
  }
  if (c.load.profile == LoadProfile::torque_cycle && c.load.points.empty()) {
    fail("load.csv_path", "a torque cycle needs at least one point");
  }
  if ((c.load.profile == LoadProfile::constant_torque || c.load.profile == LoadProfile::fan) &&
      !c.load.points.empty()) {
    fail("load.steps", fmt::format("a time table is not used with load.profile = \"{}\"",
                                   to_string(c.load.profile)));
  }
}

PlantConfig parse_plant_config(std::string_view toml_text, std::string_view source_name,
                               const std::filesystem::path& base_dir) {
  toml::table root;
  try {
    root = toml::parse(toml_text, source_name);
  } catch (const toml::parse_error& e) {
    throw ConfigError(fmt::format("{}:{}:{}: {}", source_name, e.source().begin.line,
                                  e.source().begin.column, e.description()));
  }
  auto fail = [&](const toml::node& node, std::string_view key, std::string_view message) {
    throw ConfigError(
        fmt::format("{}:{}: {}: {}", source_name, node.source().begin.line, key, message));
  };

  // Unknown sections and keys are errors: a typo must not silently fall back to a default.
  std::set<std::string> sections;
  for (const Field& f : fields()) {
    sections.emplace(f.key.substr(0, f.key.find('.')));
  }
  for (const auto& [section_key, section_node] : root) {
    const std::string section(section_key.str());
    const auto* table = section_node.as_table();
    if (table == nullptr || sections.count(section) == 0) {
      std::string hint;
      for (const std::string& s : sections) {
        if (edit_distance(section, s) <= 2) {
          hint = fmt::format(" (did you mean [{}]?)", s);
        }
      }
      fail(section_node, section,
           table == nullptr ? fmt::format("unknown key; every key belongs to a [section]{}", hint)
                            : fmt::format("unknown section{}", hint));
    }
    for (const auto& [key, node] : *table) {
      const std::string full = fmt::format("{}.{}", section, key.str());
      if (find_field(full) == nullptr) {
        fail(node, full, fmt::format("unknown key{}", suggestion(full)));
      }
    }
  }

  PlantConfig config;
  std::set<std::string_view> present;
  for (const Field& f : fields()) {
    const toml::node* node = lookup(root, f.key);
    if (node == nullptr) {
      continue;
    }
    present.insert(f.key);
    try {
      read_field(f, *node, config);
    } catch (const KeyError& e) {
      fail(*node, f.key, e.message);
    }
  }

  // Time tables belong to one profile each; a table given for another profile is a mistake.
  auto reject_unless = [&](std::string_view key, bool allowed, std::string_view profile) {
    if (present.count(key) != 0 && !allowed) {
      fail(*lookup(root, key), key,
           fmt::format("only used with load.profile = \"{}\"", profile));
    }
  };
  const LoadProfile profile = config.load.profile;
  reject_unless("load.steps", profile == LoadProfile::torque_steps, "steps");
  reject_unless("load.speed_points", profile == LoadProfile::speed_cycle, "speed");
  reject_unless("load.csv_path", profile == LoadProfile::torque_cycle, "csv");
  if (present.count("load.steps") != 0 && present.count("load.speed_points") != 0) {
    fail(*lookup(root, "load.speed_points"), "load.speed_points",
         "give either load.steps or load.speed_points");
  }
  if (profile == LoadProfile::torque_cycle) {
    // "csv": the file decides between a torque cycle and an imposed speed.
    if (present.count("load.csv_path") == 0 || config.load.csv_path.empty()) {
      throw ConfigError(fmt::format("{}: load.csv_path: required with load.profile = \"csv\"",
                                    source_name));
    }
    std::filesystem::path csv = config.load.csv_path;
    if (csv.is_relative() && !base_dir.empty()) {
      csv = base_dir / csv;
    }
    try {
      load_drive_cycle_csv(csv, config.load);
    } catch (const ConfigError& e) {
      throw ConfigError(fmt::format("{}: {}", source_name, e.what()));
    }
  }

  try {
    validate_plant_config(config);
  } catch (const ConfigError& e) {
    throw ConfigError(fmt::format("{}: {}", source_name, e.what()));
  }
  return config;
}

PlantConfig load_plant_config(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw ConfigError(fmt::format("{}: cannot open file", path.string()));
  }
  std::ostringstream text;
  text << in.rdbuf();
  return parse_plant_config(text.str(), path.string(), path.parent_path());
}

std::vector<std::string> plant_config_keys() {
  std::vector<std::string> keys;
  for (const Field& f : fields()) {
    keys.emplace_back(f.key);
  }
  return keys;
}

std::string plant_config_reference_markdown() {
  PlantConfig defaults;
  std::string out = "| key | type | default | range | meaning |\n|---|---|---|---|---|\n";
  for (const Field& f : fields()) {
    std::string range = "";
    if (f.kind == Kind::choice) {
      for (const Choice& ch : f.choices) {
        range += fmt::format("{}`{}`", range.empty() ? "" : ", ", ch.name);
      }
    } else if (f.kind != Kind::boolean && f.kind != Kind::path) {
      range = f.range.describe();
    }
    // A '|' inside a cell would end it: escape the ones in formulas such as ω·|ω|.
    std::string doc;
    for (char ch : f.doc) {
      if (ch == '|') {
        doc += '\\';
      }
      doc += ch;
    }
    out += fmt::format("| `{}` | {} | `{}` | {} | {} |\n", f.key, kind_name(f.kind),
                       format_default(f, defaults), range, doc);
  }
  return out;
}

}  // namespace pmsm::plant
