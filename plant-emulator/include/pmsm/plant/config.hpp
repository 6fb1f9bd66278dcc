// Every parameter of the plant emulator, with defaults that reproduce the Table I motor of
// Wilson, Stewart & Taylor (2010) under the reference realism profile of DESIGN §5.
//
// A default-constructed PlantConfig equals plant-emulator/profiles/reference.toml. Each
// field is described once, in the key table of config.cpp (plant_schema(), on the common
// schema engine the drive and the scenarios use too), which drives parsing, range checks and
// the reference documentation (plant_config_reference_markdown()).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "config_types.hpp"

namespace pmsm::plant {

// Thrown for every configuration problem (the one ConfigError of every configuration file);
// what() names the file, line and key, e.g. "bad.toml:3: motor.ld_H: must be > 0, got -1".
using ConfigError = common::ConfigError;

// One point of a time table (load steps, drive cycles, speed profiles); value in N·m or
// rad/s, depending on the profile.
using TimePoint = common::TimePoint;

struct SimulationConfig {
  std::uint64_t seed = 1;  // seeds the sensor noise (std::mt19937_64)
  int substeps = 1;        // RK4 steps per PWM period at least (each split at the bridge's kinks)
  // More steps where the rotor frame turns further than this (electrical rad) in one step.
  double max_step_angle_rad = 0.05;
};

// Table I motor in the amplitude-invariant dq model (Eq. 2, Eq. 3). See docs/plant.md for
// the interpretation of each Table I entry.
struct MotorConfig {
  int pole_pairs = 3;
  double rs_ohm = 0.133;          // phase-to-neutral stator resistance at rs_reference_temp_C
  double rs_reference_temp_C = 25.0;    // T0 of Eq. 1
  // Eq. 1's temperature coefficient at rs_reference_temp_C. Absent: the conductor's,
  // 1 / (K + rs_reference_temp_C) with K its inferred zero-resistance temperature (copper
  // 234.5 C: 3.85e-3 /C at 25 C; aluminium 225 C). A given value holds linearly from the
  // reference (0: a resistance that does not change, for tests).
  std::optional<double> alpha_per_C;
  double conductor_inferred_zero_C = 234.5;
  [[nodiscard]] double alpha_at_reference() const {
    return alpha_per_C.value_or(1.0 / (conductor_inferred_zero_C + rs_reference_temp_C));
  }
  // The winding's resistance at temp_C (Eq. 1, linear from the reference): the plant's law.
  [[nodiscard]] double rs_at_C(double temp_C) const {
    return rs_ohm * (1.0 + alpha_at_reference() * (temp_C - rs_reference_temp_C));
  }
  // A motor cable in series with each phase, at 20 C (copper), at the ambient temperature: in
  // the electrical model, its loss outside the machine (not in the thermal network). 0: none.
  double cable_resistance_ohm = 0.0;
  [[nodiscard]] double cable_at_C(double ambient_C) const {
    return cable_resistance_ohm * (234.5 + ambient_C) / (234.5 + 20.0);
  }
  double ke_V_s_per_rad = 1.19;       // line-to-line RMS volts per mechanical rad/s (Table I)
  double ld_H = 5.5e-3;           // half the line-to-line inductance of Table I
  double lq_H = 5.5e-3;
  double magnet_temp_coefficient_per_C = -0.0012;  // NdFeB remanence coefficient
  double magnet_ref_temp_C = 25.0;           // magnet temperature at which Ke holds
};

// Optional magnetic saturation: each axis has the flux-current curve
// psi(i) = L_sat·i + (L - L_sat)·i_knee·x/sqrt(1 + x²), x = i/i_knee (no cross-saturation).
struct SaturationConfig {
  bool enabled = false;
  double ld_sat_H = 4.5e-3;  // incremental d inductance far beyond the knee
  double lq_sat_H = 3.0e-3;
  double id_knee_A = 150.0;
  double iq_knee_A = 80.0;
};

enum class EmfShape { sinusoidal, modular, trapezoidal, custom };

struct EmfConfig {
  EmfShape shape = EmfShape::trapezoidal;
  // Used when shape == custom: odd, non-triplen orders >= 5 and their amplitudes relative to
  // the fundamental of the phase EMF (signed; see docs/plant.md for the sign convention).
  std::vector<int> custom_orders;
  std::vector<double> custom_amplitudes;
};

struct CoggingConfig {
  bool enabled = false;
  double amplitude_Nm = 0.2;
  int order = 36;            // cycles per mechanical revolution (LCM of slots and poles)
  double phase_rad = 0.0;
};

struct MechanicsConfig {
  double inertia_kg_m2 = 0.00841;         // total inertia on the shaft
  double coulomb_Nm = 0.908;        // kinetic Coulomb friction (Table I)
  double breakaway_Nm = 0.908;      // static friction; the shaft stays stuck below it
  double viscous_Nm_s_rad = 5.0e-4;
  double initial_speed_rad_s = 0.0;
  double initial_angle_rad = 0.0;   // mechanical angle of the rotor d-axis from phase a
};

enum class LoadProfile {
  constant_torque,  // torque_Nm
  torque_steps,     // torque_Nm until the first step, then piecewise constant
  fan,              // torque_Nm + fan_k_Nm_s2·ω·|ω|
  torque_cycle,     // piecewise linear torque table (drive cycle CSV with torque_Nm)
  speed_cycle,      // imposed speed (dynamometer): constant or piecewise linear table
};

struct LoadConfig {
  LoadProfile profile = LoadProfile::constant_torque;
  double torque_Nm = 0.0;        // positive load torque opposes positive rotation
  std::vector<TimePoint> points; // steps, torque cycle or speed cycle, times ascending
  double fan_k_Nm_s2 = 0.0;
  double speed_rad_s = 0.0;      // speed_cycle without points: constant imposed speed
  double dyno_bandwidth_Hz = 0.0;  // 0: ideal dynamometer (speed imposed exactly)
  std::filesystem::path csv_path;  // where points came from, for messages only
  bool ripple_enabled = true;
  double ripple_fraction = 0.02;   // load-torque ripple amplitude relative to the load torque
  double ripple_order = 2.0;       // ripple cycles per mechanical revolution
  double ripple_phase_rad = 0.0;
};

struct InverterConfig {
  double pwm_frequency_Hz = 10000.0;  // also the sampling and control rate
  double dc_bus_V = 650.0;
  bool dc_ripple_enabled = true;
  double dc_ripple_fraction = 0.01;   // peak ripple relative to dc_bus_V
  double dc_ripple_frequency_Hz = 300.0;
  // The supply behind the DC link: its voltage over time (empty: dc_bus_V throughout) and its
  // resistance (0: a stiff bus), which with the link's capacitance makes the bus sag while
  // motoring and rise while braking. The bus is held for a period and moves between periods.
  std::vector<TimePoint> dc_source_points;
  double dc_source_resistance_ohm = 0.0;
  double dc_link_capacitance_F = 1.0e-3;
  bool dead_time_enabled = true;
  double dead_time_s = 1.0e-6;
  bool device_drop_enabled = true;
  double device_drop_V = 1.0;
  double zero_current_band_A = 0.75;  // half the peak-to-peak PWM ripple current
  int computation_delay_periods = 1;  // 1: command from sample k acts in period k+1
  bool overcurrent_trip_enabled = true;
  double overcurrent_trip_A = 180.0;
};

struct CurrentAdcConfig {
  int bits = 12;
  double range_A = 200.0;  // full scale is ±range_A
  bool noise_enabled = true;
  double noise_A = 0.2;    // standard deviation per sample
  bool offset_enabled = true;
  std::array<double, 3> offset_A{0.10, -0.10, 0.05};
  bool gain_error_enabled = true;
  std::array<double, 3> gain_error{0.005, -0.005, 0.0025};  // relative, per phase
};

struct EncoderConfig {
  int bits = 14;
  double offset_rad = 0.0;  // mechanical angle read as count 0
};

struct DcBusAdcConfig {
  int bits = 12;
  double full_scale_V = 1000.0;  // code = V / (full_scale_V / 2^bits)
  bool noise_enabled = true;
  double noise_V = 0.5;
};

struct PhaseVoltageSensingConfig {
  bool enabled = false;
  int bits = 12;
  double range_V = 400.0;  // full scale is ±range_V, phase-to-neutral
  bool noise_enabled = true;
  double noise_V = 0.2;
};

// Iron loss P = k_h·|ω_e| + k_e·ω_e², scaled by the square of the magnet flux ratio.
struct IronLossConfig {
  bool enabled = true;
  double hysteresis_W_s_rad = 0.0637;    // k_h, W per electrical rad/s
  double eddy_W_s2_rad2 = 1.014e-4;      // k_e, W per (electrical rad/s)²
  double rotor_fraction = 0.1;           // share of the iron loss heating the rotor
};

struct ThermalConfig {
  bool enabled = true;
  double ambient_C = 25.0;
  // The drive's ambient / coolant sensor reads the ambient plus this (a sensor off by its
  // tolerance, or one the drive's own heat reaches); the network's ambient is ambient_C.
  double ambient_sensor_offset_C = 0.0;
  std::optional<double> initial_C;  // all nodes; ambient when absent
  double acceleration = 1.0;        // thermal time runs this many times faster
  double winding_capacity_J_K = 3000.0;
  double housing_capacity_J_K = 16000.0;
  double rotor_capacity_J_K = 4000.0;
  double winding_to_housing_K_W = 0.05;
  double housing_to_ambient_K_W = 0.1311;  // puts the dominant time constant at 2880 s
  double rotor_to_housing_K_W = 0.1;
  double rotor_to_ambient_K_W = 2.0;
  double friction_heat_fraction = 0.5;  // share of the friction loss heating the housing
  // A shaft-mounted fan (a self-ventilated, IC411 machine): the housing's path to the ambient
  // is housing_to_ambient_K_W at fan_speed_rad_s and its conductance scales as
  // standstill_share + (1 - standstill_share) (|w| / fan_speed_rad_s)^fan_exponent
  // (forced convection over the fins, the air flow in proportion to the shaft speed).
  // 0: no shaft fan, the path does not depend on the speed.
  double fan_speed_rad_s = 0.0;
  double fan_standstill_share = 0.35;  // natural convection's share of the path at fan_speed
  double fan_exponent = 0.8;           // a turbulent boundary layer's h ~ v^0.8
};

struct PlantConfig {
  SimulationConfig simulation;
  MotorConfig motor;
  SaturationConfig saturation;
  EmfConfig emf;
  CoggingConfig cogging;
  MechanicsConfig mechanics;
  LoadConfig load;
  InverterConfig inverter;
  CurrentAdcConfig current_adc;
  EncoderConfig encoder;
  DcBusAdcConfig dc_bus_adc;
  PhaseVoltageSensingConfig phase_voltage_sensing;
  IronLossConfig iron_loss;
  ThermalConfig thermal;
};

// Permanent-magnet flux linkage (phase peak V per electrical rad/s) from Table I's Ke
// (line-to-line RMS V per mechanical rad/s): psi_m = Ke·sqrt(2/3)/p.
double psi_m_from_Ke(double ke_V_s_per_rad, int pole_pairs);

// Parses a TOML file; relative CSV paths are taken relative to the file's directory.
PlantConfig load_plant_config(const std::filesystem::path& path);

// Parses TOML text; source_name prefixes every message. Relative CSV paths are taken
// relative to base_dir.
PlantConfig parse_plant_config(std::string_view toml_text, std::string_view source_name,
                               const std::filesystem::path& base_dir = {});

// Checks the cross-field rules (also run by the parsers); throws ConfigError naming the key.
void validate_plant_config(const PlantConfig& config);

// Reads a drive cycle: a header with time_s and one of speed_rad_s / torque_Nm, then rows.
// Sets load.profile, load.points and load.csv_path. Errors name `key`.
void load_drive_cycle_csv(const std::filesystem::path& path, LoadConfig& load,
                          std::string_view key = "load.csv_path");

// The key table (common schema engine) of every plant parameter.
const common::ConfigSchema<PlantConfig>& plant_schema();

// Every TOML key as "section.key", in table order.
std::vector<std::string> plant_config_keys();

// The key reference (key, type, default, range, meaning) as a Markdown table.
std::string plant_config_reference_markdown();

std::string_view to_string(EmfShape shape);
std::string_view to_string(LoadProfile profile);

}  // namespace pmsm::plant
