// The plant emulator: PMSM (dq model of Eq. 3 with saliency, optional saturation and EMF
// harmonics), average-model inverter with dead time, device drop and diode freewheeling,
// mechanics with friction and load profiles, thermal network, and the sensor front end.
//
// Timing: sample k is taken at t_k = k·Ts, the middle of the PWM carrier, where the average
// model's current equals the sampled current. step(cmd) simulates period k = [t_k, t_k+1)
// with the command latched for it (the previous call's cmd; initially gates off), latches
// `cmd` for period k+1 (the one-period computation delay of a real drive) and returns sample
// k+1. A command computed from sample k therefore first shows in sample k+2.
//
// Written independently of core/: only the plain data types of hal/messages.hpp are shared.
#pragma once

#include <array>
#include <cstdint>
#include <memory>

#include "pmsm/hal/messages.hpp"
#include "pmsm/plant/config.hpp"

namespace pmsm::plant {

// Energy meters, integrated with the same RK4 weights as the state, so that they are as
// accurate as the simulation itself (a power analyser on the terminals and a torque flange).
struct EnergyMeters {
  double input_J = 0.0;     // ∫ Σ v_xn·i_x dt at the inverter's terminals (phase-to-neutral; the cable's, if any, in it)
  double copper_J = 0.0;    // ∫ 3/2·Rs·(id² + iq²) dt
  double iron_J = 0.0;      // ∫ iron-loss power dt
  double friction_J = 0.0;  // ∫ (Coulomb + viscous friction torque)·ω dt
  double load_J = 0.0;      // ∫ T_load·ω dt: work delivered to the load or dynamometer
  double cable_J = 0.0;     // ∫ 3/2·R_cable·(id² + iq²) dt: the motor cable's loss (motor.cable_resistance_ohm)
};

// The true state, for tests and diagnostics. Never part of what the controller sees.
struct PlantState {
  double time_s = 0.0;
  double id_A = 0.0;
  double iq_A = 0.0;
  std::array<double, 3> phase_current_A{};
  double theta_m_rad = 0.0;      // mechanical angle of the rotor d-axis from phase a, [0, 2π)
  double theta_e_rad = 0.0;      // p·theta_m, wrapped to [0, 2π)
  double omega_m_rad_s = 0.0;
  double omega_e_rad_s = 0.0;
  std::array<double, 3> phase_emf_V{};  // instantaneous phase-to-neutral EMF
  double psi_m_Wb = 0.0;         // magnet flux linkage at the magnet temperature
  double rs_ohm = 0.0;           // phase-to-neutral resistance the drive sees: the winding at its temperature, and a cable at the ambient
  double winding_temp_C = 0.0;
  double housing_temp_C = 0.0;
  double magnet_temp_C = 0.0;
  double ambient_C = 0.0;
  double torque_em_Nm = 0.0;     // air-gap torque from the currents, incl. reluctance torque
  double cogging_torque_Nm = 0.0;
  double load_torque_Nm = 0.0;   // torque taken by the load (positive opposes rotation)
  double dc_bus_V = 0.0;
  std::array<double, 3> phase_voltage_avg_V{};  // phase-to-neutral, mean over last period
  double copper_loss_W = 0.0;    // means over the last period
  double iron_loss_W = 0.0;
  double friction_loss_W = 0.0;
  bool gates_enabled = false;    // the gates switch in the current period
  bool overcurrent_tripped = false;
  bool shaft_stuck = false;      // held by static friction
  EnergyMeters energy;
};

// One thread at a time: the const accessors (state(), truth()) may fill caches of the model's
// evaluation, so even they must not run concurrently with each other or with step(). Every user
// owns its Plant on one thread (PlantNode's run thread; a simulation and its twin each their own).
class Plant {
 public:
  explicit Plant(const PlantConfig& config);
  ~Plant();
  Plant(const Plant&);
  Plant& operator=(const Plant&);
  Plant(Plant&&) noexcept;
  Plant& operator=(Plant&&) noexcept;

  // Sample k, taken at the start of period k.
  [[nodiscard]] const hal::SensorSample& sample() const;

  // Simulates period k with the latched command, latches cmd for period k+1, returns
  // sample k+1. Does not allocate.
  const hal::SensorSample& step(const hal::InverterCommand& cmd);

  // Test hook: simulates period k with rotor-frame voltages vd_V, vq_V applied directly
  // (an ideal voltage source that turns with the rotor), bypassing the inverter. The
  // latched command is left as it is. Returns sample k+1.
  const hal::SensorSample& step_with_dq_voltage(double vd_V, double vq_V);

  // Ground truth at sample k (thermocouples, torque flange, speed).
  [[nodiscard]] hal::TruthSample truth() const;
  [[nodiscard]] PlantState state() const;

  [[nodiscard]] double time_s() const;
  [[nodiscard]] std::uint32_t period() const;
  [[nodiscard]] double period_s() const;
  [[nodiscard]] const PlantConfig& config() const;

  // Commands whose sequence did not match the sample they should have been computed from.
  [[nodiscard]] std::uint64_t command_sequence_errors() const;

  // The model's state came out no number (NaN or infinite) at some period: a machine its
  // integration cannot follow, which validate_plant_config's time-constant rule keeps out, or
  // a non-finite input through step_with_dq_voltage. The samples after it are meaningless
  // (their codes are defined: 0); a caller stops and says so. diverged_at_s() is the start of
  // the first such period (-1 while finite).
  [[nodiscard]] bool diverged() const;
  [[nodiscard]] double diverged_at_s() const;

  // Run-time changes for scenarios (no allocation).
  void set_ambient_C(double ambient_C);
  void set_temperatures_C(double winding_C, double housing_C, double rotor_C);
  void set_load_torque_Nm(double torque_Nm);         // switches to a constant load torque
  void set_imposed_speed_rad_s(double speed_rad_s);  // switches to a constant-speed dyno
  // Changes the thermal acceleration (the temperatures carry on). Recomputes the network's
  // discretisation: not for every period, but it does not allocate.
  void set_thermal_acceleration(double acceleration);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pmsm::plant
