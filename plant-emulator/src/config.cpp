// TOML configuration of the plant. One key table (plant_schema(), on the common schema engine
// of common/config_schema.hpp, the same one the drive and the scenarios use) describes every
// key once: its place in PlantConfig, type, range and meaning. Parsing, range checks, the
// unknown-key check and the Markdown reference in docs/plant.md are all driven by it.
#include "pmsm/plant/config.hpp"
#include "pmsm/plant/emf.hpp"

#include "config_schema.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include <fmt/format.h>
#include <toml++/toml.h>

namespace pmsm::plant {
namespace {

using common::ValueRange;

constexpr std::size_t kMaxHarmonics = 12;

// The plant's names for the ranges of the common engine.
// An angle, in radians: within a thousand of them (about 160 turns) either way. A number far
// beyond is a typo, and the shaft's angle kept at 1e300 rad lost every digit it turns by (the
// drive saw a shaft at -380 rad/s where it ran at 60).
ValueRange angle() { return common::between(-1000.0, 1000.0); }
ValueRange positive(double hi = std::numeric_limits<double>::infinity()) { return common::positive(hi); }
ValueRange non_negative(double hi = std::numeric_limits<double>::infinity()) { return common::at_least(0.0, hi); }
ValueRange closed(double lo, double hi) { return common::between(lo, hi); }

// Accessor for one member of PlantConfig.
#define PMSM_MEMBER(member) [](PlantConfig& c) -> auto& { return c.member; }

common::ConfigSchema<PlantConfig> build_schema() {
  common::ConfigSchema<PlantConfig> s;
  // The plant's units are in its key names (ohm, H, V, A, ...): no unit column of their own.
  auto real = [&s](std::string key, common::ConfigSchema<PlantConfig>::RealAccess access, ValueRange range,
                   std::string doc) { s.real(std::move(key), std::move(access), range, "", std::move(doc)); };
  auto integer = [&s](std::string key, common::ConfigSchema<PlantConfig>::IntAccess access, ValueRange range,
                      std::string doc) { s.integer(std::move(key), std::move(access), range, std::move(doc)); };
  auto boolean = [&s](std::string key, common::ConfigSchema<PlantConfig>::BoolAccess access, std::string doc) {
    s.boolean(std::move(key), std::move(access), std::move(doc));
  };
  auto real3 = [&s](std::string key, common::ConfigSchema<PlantConfig>::Real3Access access, ValueRange range,
                    std::string doc) { s.real3(std::move(key), std::move(access), range, "", std::move(doc)); };
    // [simulation]
    s.seed("simulation.seed", PMSM_MEMBER(simulation.seed),
           "Seed of the sensor-noise generator (std::mt19937_64). The same seed gives a "
           "bit-identical sample stream.");
    integer("simulation.substeps", PMSM_MEMBER(simulation.substeps), closed(1, 64),
                        "RK4 integration steps per PWM period at least; each is also split where a phase current "
                        "crosses a kink of the bridge's voltage (docs/plant.md, Numerics).");
    real("simulation.max_step_angle_rad", PMSM_MEMBER(simulation.max_step_angle_rad), closed(0.001, 1.0),
         "Largest electrical angle the rotor turns in one RK4 step: a period takes more steps than "
         "simulation.substeps where the speed asks for it (0.05: two at the reference's rated speed).");
    // [motor]
    integer("motor.pole_pairs", PMSM_MEMBER(motor.pole_pairs), closed(1, 64),
                        "Pole pairs p (Table I: 3).");
    // The drive's configuration takes the same ranges (drive/controller_config.cpp).
    real("motor.rs_ohm", PMSM_MEMBER(motor.rs_ohm), closed(common::kMinStatorResistance_ohm, common::kMaxStatorResistance_ohm),
                     "Phase-to-neutral stator resistance Rs0 at rs_reference_temp_C (Table I: "
                     "0.133 Ω at 25 °C).");
    real("motor.rs_reference_temp_C", PMSM_MEMBER(motor.rs_reference_temp_C), closed(-50, 250),
                     "Temperature T0 at which rs_ohm holds (Eq. 1).");
    s.optional_real("motor.alpha_per_C", [](PlantConfig& c) -> std::optional<double>& { return c.motor.alpha_per_C; },
                    closed(0, 0.01), "/°C", "the conductor's, 1 / (K + rs_reference_temp_C)",
                    "Temperature coefficient of the winding resistance at rs_reference_temp_C, Eq. 1, held linear "
                    "from there (copper: 3.85e-3 at 25 °C).");
    s.choice("motor.conductor",
             {{"copper", 0}, {"aluminium", 1}},
             [](const PlantConfig& c) { return c.motor.conductor_inferred_zero_C == 225.0 ? 1 : 0; },
             [](PlantConfig& c, int v) { c.motor.conductor_inferred_zero_C = v == 1 ? 225.0 : 234.5; },
             "Winding conductor: resistance proportional to K + T, K = 234.5 °C for copper, 225 °C for aluminium.");
    real("motor.cable_resistance_ohm", PMSM_MEMBER(motor.cable_resistance_ohm),
         closed(0, common::kMaxStatorResistance_ohm),
         "A motor cable in series with each phase, ohm at 20 °C (copper), at the ambient temperature: it adds to "
         "the resistance the drive sees, and its loss stays outside the machine's thermal network (0: none).");
    real("motor.ke_V_s_per_rad", PMSM_MEMBER(motor.ke_V_s_per_rad), closed(common::kMinEmfConstant_V_s_per_rad, 100.0),
                     "EMF constant of Table I: line-to-line RMS volts per mechanical rad/s, "
                     "at magnet_ref_temp_C. psi_m = Ke·sqrt(2/3)/p.");
    real("motor.ld_H", PMSM_MEMBER(motor.ld_H), closed(common::kMinInductance_H, 1.0),
                     "d-axis inductance (default L_ll/2 of Table I).");
    real("motor.lq_H", PMSM_MEMBER(motor.lq_H), closed(common::kMinInductance_H, 1.0),
                     "q-axis inductance; Lq != Ld gives reluctance torque.");
    real("motor.magnet_temp_coefficient_per_C", PMSM_MEMBER(motor.magnet_temp_coefficient_per_C),
                     closed(-0.01, 0.0),
                     "Relative change of the magnet flux per kelvin (NdFeB about -0.12 %/K).");
    real("motor.magnet_ref_temp_C", PMSM_MEMBER(motor.magnet_ref_temp_C),
                     closed(-50, 250), "Magnet temperature at which ke_V_s_per_rad holds.");
    // [saturation]
    boolean("saturation.enabled", PMSM_MEMBER(saturation.enabled),
                        "Magnetic saturation of both axes (no cross-saturation).");
    real("saturation.ld_sat_H", PMSM_MEMBER(saturation.ld_sat_H), closed(common::kMinInductance_H, 1.0),
                     "Incremental d-axis inductance far beyond the knee (<= motor.ld_H).");
    real("saturation.lq_sat_H", PMSM_MEMBER(saturation.lq_sat_H), closed(common::kMinInductance_H, 1.0),
                     "Incremental q-axis inductance far beyond the knee (<= motor.lq_H).");
    real("saturation.id_knee_A", PMSM_MEMBER(saturation.id_knee_A), positive(1e4),
                     "d-axis current at the knee of the saturation curve.");
    real("saturation.iq_knee_A", PMSM_MEMBER(saturation.iq_knee_A), positive(1e4),
                     "q-axis current at the knee of the saturation curve.");
    // [emf]
    s.choice("emf.shape",
             {{"sinusoidal", static_cast<int>(EmfShape::sinusoidal)},
              {"modular", static_cast<int>(EmfShape::modular)},
              {"trapezoidal", static_cast<int>(EmfShape::trapezoidal)},
              {"custom", static_cast<int>(EmfShape::custom)}},
             [](const PlantConfig& c) { return static_cast<int>(c.emf.shape); },
             [](PlantConfig& c, int v) { c.emf.shape = static_cast<EmfShape>(v); },
             "Back-EMF waveform (Fig. 11): sinusoidal 100 %, modular 89 %, trapezoidal 77 % "
             "fundamental (fundamental / peak, fundamental fixed by Ke), or custom.");
    s.int_list("emf.harmonic_orders", kMaxHarmonics, closed(5, kMaxEmfOrder), PMSM_MEMBER(emf.custom_orders),
               "shape = \"custom\": harmonic orders n (odd, not multiples of 3, at most 12).");
    s.list("emf.harmonic_amplitudes", 0, kMaxHarmonics, closed(-1, 1),
           [](const PlantConfig& c) { return c.emf.custom_amplitudes; },
           [](PlantConfig& c, const std::vector<double>& v) { c.emf.custom_amplitudes = v; }, "",
           "shape = \"custom\": b_n relative to the fundamental, phase EMF "
           "-(sin θ + Σ b_n sin nθ)·ω_e·psi_m.");
    // [cogging]
    boolean("cogging.enabled", PMSM_MEMBER(cogging.enabled),
                        "Cogging torque amplitude·sin(order·θ_m + phase).");
    real("cogging.amplitude_Nm", PMSM_MEMBER(cogging.amplitude_Nm),
                     non_negative(100.0), "Cogging torque amplitude.");
    integer("cogging.order", PMSM_MEMBER(cogging.order), closed(1, 1000),
                        "Cogging cycles per mechanical revolution.");
    real("cogging.phase_rad", PMSM_MEMBER(cogging.phase_rad), angle(),
                     "Cogging phase.");
    // [mechanics]
    real("mechanics.inertia_kg_m2", PMSM_MEMBER(mechanics.inertia_kg_m2), closed(common::kMinInertia_kg_m2, common::kMaxInertia_kg_m2),
                     "Total inertia on the shaft (Table I rotor: 0.00841).");
    real("mechanics.coulomb_Nm", PMSM_MEMBER(mechanics.coulomb_Nm),
                     non_negative(1e3), "Kinetic Coulomb friction (Table I: 0.908).");
    real("mechanics.breakaway_Nm", PMSM_MEMBER(mechanics.breakaway_Nm),
                     non_negative(1e3),
                     "Static friction: a stopped shaft stays stuck while the net driving "
                     "torque is below it (>= coulomb_Nm).");
    real("mechanics.viscous_Nm_s_rad", PMSM_MEMBER(mechanics.viscous_Nm_s_rad),
                     non_negative(10.0), "Viscous friction coefficient.");
    real("mechanics.initial_speed_rad_s", PMSM_MEMBER(mechanics.initial_speed_rad_s),
                     closed(-2000, 2000), "Mechanical speed at t = 0.");
    real("mechanics.initial_angle_rad", PMSM_MEMBER(mechanics.initial_angle_rad),
                     angle(), "Mechanical angle of the rotor d-axis from phase a at t = 0.");
    // [load]
    s.choice("load.profile",
             {{"constant", static_cast<int>(LoadProfile::constant_torque)},
              {"steps", static_cast<int>(LoadProfile::torque_steps)},
              {"fan", static_cast<int>(LoadProfile::fan)},
              {"csv", static_cast<int>(LoadProfile::torque_cycle)},
              {"speed", static_cast<int>(LoadProfile::speed_cycle)}},
             [](const PlantConfig& c) { return static_cast<int>(c.load.profile); },
             [](PlantConfig& c, int v) { c.load.profile = static_cast<LoadProfile>(v); },
             "constant: torque_Nm. steps: torque_Nm, then the steps table. fan: torque_Nm + "
             "fan_k_Nm_s2·ω·|ω|. csv: drive cycle file (torque_Nm column: load torque; "
             "speed_rad_s column: imposed speed). speed: dynamometer imposing speed_rad_s "
             "or the speed_points table.");
    real("load.torque_Nm", PMSM_MEMBER(load.torque_Nm), closed(-1e4, 1e4),
                     "Constant load torque (positive opposes positive rotation); the initial "
                     "value for steps, the offset for fan.");
    s.points("load.steps", closed(-1e4, 1e4), PMSM_MEMBER(load.points), "",
             "profile = \"steps\": [[time_s, torque_Nm], ...], times ascending; each torque "
             "holds from its time on.");
    real("load.fan_k_Nm_s2", PMSM_MEMBER(load.fan_k_Nm_s2), closed(-10, 10),
                     "profile = \"fan\": k of T = k·ω·|ω| (fan or pump).");
    s.path("load.csv_path", PMSM_MEMBER(load.csv_path),
           "profile = \"csv\": drive cycle with a header: time_s and either speed_rad_s or "
           "torque_Nm; linear interpolation, ends held. Relative to the TOML file.");
    real("load.speed_rad_s", PMSM_MEMBER(load.speed_rad_s), closed(-2000, 2000),
                     "profile = \"speed\" without speed_points: constant imposed speed.");
    s.points("load.speed_points", closed(-2000, 2000), PMSM_MEMBER(load.points), "",
             "profile = \"speed\": [[time_s, speed_rad_s], ...], linear interpolation (repeat "
             "a time for a step), ends held.");
    real("load.dyno_bandwidth_Hz", PMSM_MEMBER(load.dyno_bandwidth_Hz),
                     non_negative(1000.0),
                     "Imposed speed: 0 = ideal dynamometer (speed exact); > 0 = PI speed "
                     "loop of this bandwidth acting through the load torque.");
    boolean("load.ripple_enabled", PMSM_MEMBER(load.ripple_enabled),
                        "Load-torque ripple T·(1 + fraction·sin(order·θ_m + phase)).");
    real("load.ripple_fraction", PMSM_MEMBER(load.ripple_fraction), closed(0, 1),
                     "Ripple amplitude relative to the load torque (reference: 2 %).");
    real("load.ripple_order", PMSM_MEMBER(load.ripple_order), positive(1000.0),
                     "Ripple cycles per mechanical revolution.");
    real("load.ripple_phase_rad", PMSM_MEMBER(load.ripple_phase_rad), angle(),
                     "Ripple phase.");
    // [inverter]
    real("inverter.pwm_frequency_Hz", PMSM_MEMBER(inverter.pwm_frequency_Hz),
                     closed(1000, 100000), "PWM, sampling and control frequency fs (every SENSOR_SAMPLE reports its period, PwmPeriod).");
    real("inverter.dc_bus_V", PMSM_MEMBER(inverter.dc_bus_V), closed(common::kMinDcBus_V, 2000.0),
                     "Nominal DC-bus voltage.");
    boolean("inverter.dc_ripple_enabled", PMSM_MEMBER(inverter.dc_ripple_enabled),
                        "DC-bus ripple Vdc·(1 + fraction·sin(2π·f·t)).");
    real("inverter.dc_ripple_fraction", PMSM_MEMBER(inverter.dc_ripple_fraction),
                     closed(0, 0.5), "DC-bus ripple amplitude (peak) relative to dc_bus_V.");
    real("inverter.dc_ripple_frequency_Hz",
                     PMSM_MEMBER(inverter.dc_ripple_frequency_Hz), positive(1e5),
                     "DC-bus ripple frequency (six-pulse rectifier on 50 Hz: 300 Hz).");
    s.points("inverter.dc_source_points", closed(common::kMinDcBus_V, 2000.0), PMSM_MEMBER(inverter.dc_source_points), "",
             "[[time_s, V], ...]: the supply's voltage over time in place of dc_bus_V (a sag, a step, a "
             "battery discharging): linear interpolation (repeat a time for a step), ends held. The bus "
             "moves between PWM periods; the ripple is relative to it.");
    real("inverter.dc_source_resistance_ohm", PMSM_MEMBER(inverter.dc_source_resistance_ohm),
         closed(0, 1000),
         "Resistance of the supply behind the DC link (a battery's internal resistance, cables, a weak "
         "rectifier): the bus falls by R x the DC current while motoring and rises while braking (no "
         "brake chopper). 0: a stiff bus.");
    real("inverter.dc_link_capacitance_F", PMSM_MEMBER(inverter.dc_link_capacitance_F), positive(10.0),
         "The DC link's capacitance: with dc_source_resistance_ohm it sets how fast the bus follows "
         "the load (time constant R x C).");
    boolean("inverter.dead_time_enabled", PMSM_MEMBER(inverter.dead_time_enabled),
                        "Dead-time voltage error (not compensated by the plant).");
    real("inverter.dead_time_s", PMSM_MEMBER(inverter.dead_time_s),
                     non_negative(1e-4), "Dead time Td per switching edge pair.");
    boolean("inverter.device_drop_enabled",
                        PMSM_MEMBER(inverter.device_drop_enabled),
                        "Forward drop of the conducting switch or diode.");
    real("inverter.device_drop_V", PMSM_MEMBER(inverter.device_drop_V),
                     non_negative(20.0), "Device forward drop, opposing the phase current.");
    real("inverter.zero_current_band_A", PMSM_MEMBER(inverter.zero_current_band_A),
                     positive(100.0),
                     "Half the peak-to-peak PWM ripple: below it the dead-time and drop "
                     "errors fall linearly to zero with the current.");
    integer("inverter.computation_delay_periods",
                        PMSM_MEMBER(inverter.computation_delay_periods), closed(0, 1),
                        "1: a command computed from sample k acts in period k+1 (a real "
                        "drive); 0: in period k (debugging only).");
    boolean("inverter.overcurrent_trip_enabled",
                        PMSM_MEMBER(inverter.overcurrent_trip_enabled),
                        "Hardware over-current comparator: turns the gates off, latched until "
                        "a command with enable = false.");
    real("inverter.overcurrent_trip_A", PMSM_MEMBER(inverter.overcurrent_trip_A),
                     positive(1e4), "Trip level on any phase current at a sample instant.");
    // [current_adc]
    integer("current_adc.bits", PMSM_MEMBER(current_adc.bits), closed(2, 16),
                        "Phase-current ADC resolution; codes are signed, LSB = "
                        "range_A / 2^(bits-1).");
    real("current_adc.range_A", PMSM_MEMBER(current_adc.range_A), positive(1e4),
                     "Full scale ±range_A.");
    boolean("current_adc.noise_enabled", PMSM_MEMBER(current_adc.noise_enabled),
                        "Gaussian noise on each phase current.");
    real("current_adc.noise_A", PMSM_MEMBER(current_adc.noise_A), non_negative(100.0),
                     "Noise standard deviation.");
    boolean("current_adc.offset_enabled", PMSM_MEMBER(current_adc.offset_enabled),
                        "Per-phase offset.");
    real3("current_adc.offset_A", PMSM_MEMBER(current_adc.offset_A),
                      closed(-100, 100), "Offsets of phases a, b, c.");
    boolean("current_adc.gain_error_enabled",
                        PMSM_MEMBER(current_adc.gain_error_enabled), "Per-phase gain error.");
    real3("current_adc.gain_error", PMSM_MEMBER(current_adc.gain_error),
                      closed(-0.5, 0.5),
                      "Relative gain errors of phases a, b, c (measured = (1 + e)·true).");
    // [encoder]
    integer("encoder.bits", PMSM_MEMBER(encoder.bits), closed(1, 16),
                        "Absolute encoder resolution: counts 0 .. 2^bits - 1 per mechanical "
                        "revolution.");
    real("encoder.offset_rad", PMSM_MEMBER(encoder.offset_rad), angle(),
                     "Mechanical angle read as count 0.");
    // [dc_bus_adc]
    integer("dc_bus_adc.bits", PMSM_MEMBER(dc_bus_adc.bits), closed(2, 16),
                        "DC-bus ADC resolution; unsigned codes, LSB = full_scale_V / 2^bits.");
    real("dc_bus_adc.full_scale_V", PMSM_MEMBER(dc_bus_adc.full_scale_V),
                     positive(1e4), "DC-bus ADC full scale.");
    boolean("dc_bus_adc.noise_enabled", PMSM_MEMBER(dc_bus_adc.noise_enabled),
                        "Gaussian noise on the DC-bus measurement.");
    real("dc_bus_adc.noise_V", PMSM_MEMBER(dc_bus_adc.noise_V), non_negative(100.0),
                     "Noise standard deviation.");
    // [phase_voltage_sensing]
    boolean("phase_voltage_sensing.enabled",
                        PMSM_MEMBER(phase_voltage_sensing.enabled),
                        "Measure the phase-to-neutral voltages (mean over the last period) "
                        "and set kSensorPhaseVoltageValid.");
    integer("phase_voltage_sensing.bits", PMSM_MEMBER(phase_voltage_sensing.bits),
                        closed(2, 16), "Signed codes, LSB = range_V / 2^(bits-1).");
    real("phase_voltage_sensing.range_V", PMSM_MEMBER(phase_voltage_sensing.range_V),
                     positive(1e4), "Full scale ±range_V.");
    boolean("phase_voltage_sensing.noise_enabled",
                        PMSM_MEMBER(phase_voltage_sensing.noise_enabled),
                        "Gaussian noise on the phase voltages.");
    real("phase_voltage_sensing.noise_V", PMSM_MEMBER(phase_voltage_sensing.noise_V),
                     non_negative(100.0), "Noise standard deviation.");
    // [iron_loss]
    boolean("iron_loss.enabled", PMSM_MEMBER(iron_loss.enabled),
                        "Speed-dependent iron loss, taken from the shaft as a drag torque.");
    real("iron_loss.hysteresis_W_s_rad", PMSM_MEMBER(iron_loss.hysteresis_W_s_rad),
                     non_negative(100.0), "k_h of P = (k_h·|ω_e| + k_e·ω_e²)·(psi_m/psi_m0)².");
    real("iron_loss.eddy_W_s2_rad2", PMSM_MEMBER(iron_loss.eddy_W_s2_rad2),
                     non_negative(1.0), "k_e of the iron-loss formula.");
    real("iron_loss.rotor_fraction", PMSM_MEMBER(iron_loss.rotor_fraction),
                     closed(0, 1), "Share of the iron loss heating the rotor node; the rest "
                                   "heats the stator iron/housing node.");
    // [thermal]
    boolean("thermal.enabled", PMSM_MEMBER(thermal.enabled),
                        "Thermal network; when false all temperatures stay at initial_C.");
    real("thermal.ambient_C", PMSM_MEMBER(thermal.ambient_C), closed(-50, 150),
                     "Ambient temperature (changeable at run time).");
    real("thermal.ambient_sensor_offset_C", PMSM_MEMBER(thermal.ambient_sensor_offset_C), closed(-20, 20),
         "The drive's ambient / coolant sensor (SENSOR_SAMPLE's Ambient) reads the ambient plus this: a sensor off by "
         "its tolerance, or one the drive's own heat reaches. The thermal network's ambient is ambient_C.");
    s.optional_real("thermal.initial_C", PMSM_MEMBER(thermal.initial_C), closed(-50, 250), "",
                    "ambient_C", "Initial temperature of every node (default: ambient_C).");
    real("thermal.acceleration", PMSM_MEMBER(thermal.acceleration), closed(1e-3, 1e6),
                     "Thermal time runs this many times faster than electrical time.");
    real("thermal.winding_capacity_J_K", PMSM_MEMBER(thermal.winding_capacity_J_K), closed(common::kMinHeatCapacity_J_K, 1e7),
                     "Heat capacity of the winding node (copper and insulation).");
    real("thermal.housing_capacity_J_K", PMSM_MEMBER(thermal.housing_capacity_J_K), closed(common::kMinHeatCapacity_J_K, 1e7),
                     "Heat capacity of the stator iron and housing node.");
    real("thermal.rotor_capacity_J_K", PMSM_MEMBER(thermal.rotor_capacity_J_K), closed(common::kMinHeatCapacity_J_K, 1e7),
                     "Heat capacity of the rotor (magnets, rotor iron, shaft) node.");
    real("thermal.winding_to_housing_K_W", PMSM_MEMBER(thermal.winding_to_housing_K_W),
                     closed(common::kMinThermalResistance_K_W, 1e3), "Thermal resistance winding to housing.");
    real("thermal.housing_to_ambient_K_W", PMSM_MEMBER(thermal.housing_to_ambient_K_W),
                     closed(common::kMinThermalResistance_K_W, 1e3), "Thermal resistance housing to ambient.");
    real("thermal.rotor_to_housing_K_W", PMSM_MEMBER(thermal.rotor_to_housing_K_W),
                     closed(common::kMinThermalResistance_K_W, 1e3), "Thermal resistance rotor to housing (air gap, bearings).");
    real("thermal.rotor_to_ambient_K_W", PMSM_MEMBER(thermal.rotor_to_ambient_K_W),
                     closed(common::kMinThermalResistance_K_W, 1e6), "Thermal resistance rotor to ambient (shaft).");
    real("thermal.friction_heat_fraction",
                     PMSM_MEMBER(thermal.friction_heat_fraction), closed(0, 1),
                     "Share of the friction loss heating the housing node.");
    real("thermal.fan_speed_rad_s", PMSM_MEMBER(thermal.fan_speed_rad_s), closed(0, 1e4),
         "A shaft-mounted fan (a self-ventilated machine): the mechanical speed at which "
         "housing_to_ambient_K_W holds; the path's conductance scales as fan_standstill_share + (1 - "
         "fan_standstill_share) (|w| / fan_speed_rad_s)^fan_exponent. 0: no shaft fan (the path does not depend on "
         "the speed).");
    real("thermal.fan_standstill_share", PMSM_MEMBER(thermal.fan_standstill_share), closed(0.01, 1),
         "With a shaft fan: the share of the housing's path to the ambient left at standstill (natural convection).");
    real("thermal.fan_exponent", PMSM_MEMBER(thermal.fan_exponent), closed(0.1, 2),
         "With a shaft fan: how the fan's share of the path grows with the speed (0.8: forced convection, the air "
         "flow in proportion to the speed).");
  return s;
}

#undef PMSM_MEMBER

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

double psi_m_from_Ke(double ke_V_s_per_rad, int pole_pairs) {
  // Ke: line-to-line RMS volts per mechanical rad/s. Phase peak per mechanical rad/s is
  // Ke·sqrt(2)/sqrt(3); per electrical rad/s divide by p.
  return ke_V_s_per_rad * std::sqrt(2.0 / 3.0) / static_cast<double>(pole_pairs);
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
  std::string text;
  try {
    text = common::read_config_file(path, "drive cycle");
  } catch (const ConfigError& e) {
    throw ConfigError(fmt::format("{}: {}", key, e.what()));
  }
  std::istringstream in(text);
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
    if (line_no == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) {
      line.erase(0, 3);  // a UTF-8 byte-order mark (a spreadsheet's export) is no part of the header
    }
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
        for (auto& [name, column] : {std::pair<const char*, std::optional<std::size_t>&>{"time_s", tc},
                                     std::pair<const char*, std::optional<std::size_t>&>{"speed_rad_s", sc},
                                     std::pair<const char*, std::optional<std::size_t>&>{"torque_Nm", qc}}) {
          if (cells[i] == name && column.has_value()) {
            throw ConfigError(fmt::format("{}:{}: column {} appears twice in the header", where, line_no, name));
          }
          if (cells[i] == name) column = i;
        }
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
                                      col + 1, common::excerpt(cell)));
      }
      return v;
    };
    const TimePoint p{number(time_col), number(value_col)};
    // The ranges of load.speed_points and load.steps (the tables the CSV stands for), told with
    // the file and line rather than later against the table's key.
    const double limit = is_speed ? 2000.0 : 1e4;
    if (p.time_s < 0.0) {
      throw ConfigError(fmt::format("{}:{}: time_s must be >= 0, got {}", where, line_no, p.time_s));
    }
    if (std::abs(p.value) > limit) {
      throw ConfigError(fmt::format("{}:{}: {} must be in [{}, {}], got {}", where, line_no,
                                    is_speed ? "speed_rad_s" : "torque_Nm", -limit, limit, p.value));
    }
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

namespace {

// The cross-field rules; `fail(key, message)` throws; `given(key)` says whether the file gives
// the key (false for a configuration built in code), for a rule that may lie at either of two.
template <typename Fail, typename Given>
void check_rules(const PlantConfig& c, Fail&& fail, Given&& given) {
  if (c.saturation.enabled && c.saturation.ld_sat_H > c.motor.ld_H) {
    fail("saturation.ld_sat_H", fmt::format("must be <= motor.ld_H ({}), got {}", c.motor.ld_H,
                                            c.saturation.ld_sat_H));
  }
  if (c.saturation.enabled && c.saturation.lq_sat_H > c.motor.lq_H) {
    fail("saturation.lq_sat_H", fmt::format("must be <= motor.lq_H ({}), got {}", c.motor.lq_H,
                                            c.saturation.lq_sat_H));
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
    if (c.emf.custom_orders.size() > kMaxHarmonics) {
      fail("emf.harmonic_orders",
           fmt::format("at most {} harmonics, got {}", kMaxHarmonics, c.emf.custom_orders.size()));
    }
    for (std::size_t k = 0; k < c.emf.custom_orders.size(); ++k) {
      const int n = c.emf.custom_orders[k];
      // One amplitude an order: a repeated one would add its amplitudes, which no table means.
      if (std::find(c.emf.custom_orders.begin(), c.emf.custom_orders.begin() + static_cast<std::ptrdiff_t>(k), n) !=
          c.emf.custom_orders.begin() + static_cast<std::ptrdiff_t>(k)) {
        fail("emf.harmonic_orders", fmt::format("order {} is given twice", n));
      }
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
  {
    // The electrical time constant against the integration's step. A step h of RK4 on the
    // winding's decay e^(-t/tau) is stable below h/tau = 2.8 and accurate to 1e-4 at 0.5; the
    // step is at most a period over simulation.substeps. tau is taken with the smallest
    // inductance (the saturated ones where saturation is on) and the resistance doubled, as a
    // copper winding has it near 280 C: a 400 ohm winding on the reference's 0.4 mH ran away
    // to 78 million C, 0.1 nH gave NaN currents.
    std::pair<std::string_view, double> l_min{"motor.ld_H", c.motor.ld_H};
    const auto smaller = [&](std::string_view key, double l) {
      if (l < l_min.second) {
        l_min = {key, l};
      }
    };
    smaller("motor.lq_H", c.motor.lq_H);
    if (c.saturation.enabled) {
      smaller("saturation.ld_sat_H", c.saturation.ld_sat_H);
      smaller("saturation.lq_sat_H", c.saturation.lq_sat_H);
    }
    // The inverter drives the winding and the cable in series.
    const double r_ohm = c.motor.rs_ohm + c.motor.cable_resistance_ohm;
    const double tau_s = l_min.second / (2.0 * r_ohm);
    const double h_s = 1.0 / (c.inverter.pwm_frequency_Hz * c.simulation.substeps);
    if (!(h_s <= 0.5 * tau_s)) {
      const double needed = std::ceil(2.0 / (tau_s * c.inverter.pwm_frequency_Hz));
      // At the inductance's line where the file gives it and not the resistance, else at the
      // resistance's.
      const bool at_inductance = given(l_min.first) && !given("motor.rs_ohm");
      fail(at_inductance ? l_min.first : std::string_view("motor.rs_ohm"),
           fmt::format("the winding's electrical time constant, the smallest inductance ({} = {} H) over twice "
                       "{} ({} ohm), {:.3g} s, is shorter than two integration steps (1 / "
                       "(inverter.pwm_frequency_Hz x simulation.substeps) = {:.3g} s): the model would diverge; check "
                       "the resistance and the inductances, or raise simulation.substeps to {}",
                       l_min.first, common::format_number(l_min.second),
                       c.motor.cable_resistance_ohm > 0.0 ? "motor.rs_ohm + motor.cable_resistance_ohm" : "motor.rs_ohm",
                       common::format_number(r_ohm), tau_s,
                       h_s, needed <= 64.0 ? fmt::format("{:.0f}", needed) : std::string("its 64 and lower the PWM period")));
    }
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

}  // namespace

const common::ConfigSchema<PlantConfig>& plant_schema() {
  static const common::ConfigSchema<PlantConfig> schema = build_schema();
  return schema;
}

void validate_plant_config(const PlantConfig& c) {
  // The ranges of the key table hold for configs built in code too.
  plant_schema().validate(c, "");
  check_rules(
      c, [](std::string_view key, const std::string& message) { throw ConfigError(fmt::format("{}: {}", key, message)); },
      [](std::string_view) { return false; });
}

PlantConfig parse_plant_config(std::string_view toml_text, std::string_view source_name,
                               const std::filesystem::path& base_dir) {
  if (const auto deep = common::toml_key_depth_problem(toml_text)) {
    throw ConfigError(common::toml_depth_message(*deep, source_name));
  }
  toml::table root;
  try {
    root = toml::parse(toml_text, source_name);
  } catch (const toml::parse_error& e) {
    throw ConfigError(fmt::format("{}:{}:{}: {}", source_name, e.source().begin.line,
                                  e.source().begin.column, e.description()));
  }
  // Unknown sections and keys are errors: a typo must not silently fall back to a default.
  PlantConfig config;
  plant_schema().apply(root, config, source_name);
  // "file:line: key: " of a key the file gives, "file: key: " of one it does not.
  auto at = [&](std::string_view key) { return common::key_location(root, key, source_name) + std::string(key) + ": "; };
  auto present = [&](std::string_view key) { return static_cast<bool>(root.at_path(key)); };

  // Time tables belong to one profile each; a table given for another profile is a mistake.
  auto reject_unless = [&](std::string_view key, bool allowed, std::string_view profile) {
    if (present(key) && !allowed) {
      throw ConfigError(at(key) + fmt::format("only used with load.profile = \"{}\"", profile));
    }
  };
  const LoadProfile profile = config.load.profile;
  reject_unless("load.steps", profile == LoadProfile::torque_steps, "steps");
  reject_unless("load.speed_points", profile == LoadProfile::speed_cycle, "speed");
  reject_unless("load.csv_path", profile == LoadProfile::torque_cycle, "csv");
  if (present("load.steps") && present("load.speed_points")) {
    throw ConfigError(at("load.speed_points") + "give either load.steps or load.speed_points");
  }
  if (profile == LoadProfile::torque_cycle) {
    // "csv": the file decides between a torque cycle and an imposed speed.
    if (!present("load.csv_path") || config.load.csv_path.empty()) {
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
      // "plant.toml:6: load.csv_path: cycle.csv:3: ...": the plant file's line of the key too.
      throw ConfigError(common::key_location(root, "load.csv_path", source_name) + e.what());
    }
  }

  plant_schema().validate(config, source_name);
  check_rules(
      config, [&](std::string_view key, const std::string& message) { throw ConfigError(at(key) + message); },
      [&](std::string_view key) { return static_cast<bool>(root.at_path(key)); });
  return config;
}

PlantConfig load_plant_config(const std::filesystem::path& path) {
  return parse_plant_config(common::read_config_file(path, "plant configuration"), path.string(), path.parent_path());
}

std::vector<std::string> plant_config_keys() { return plant_schema().keys(); }

std::string plant_config_reference_markdown() { return plant_schema().markdown(PlantConfig{}); }

}  // namespace pmsm::plant
