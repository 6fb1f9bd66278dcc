// DriveConfig::derive_from_motor(): the one place where the sub-configurations take their
// copies of the motor model (and of the period), so that they cannot disagree with it.
#include "pmsm/core/drive_controller.hpp"
#include "pmsm/core/speed_controller.hpp"

namespace pmsm::core {

void DriveConfig::derive_from_motor() {
  const double psi_Wb = flux_linkage_Wb(motor);
  // What the drive sees: the winding's nameplate resistance and a motor cable's, if any.
  const double rs_seen_ohm = terminal_resistance_ohm(*this);
  current.period_s = period_s;
  current.rs_ohm = rs_seen_ohm;
  current.ld_H = motor.ld_H;
  current.lq_H = motor.lq_H;
  current.flux_linkage_Wb = psi_Wb;
  speed.period_s = period_s * speed_decimation;
  speed.inertia_kg_m2 = motor.inertia_kg_m2;
  angle.period_s = period_s;
  angle.pole_pairs = motor.pole_pairs;
  angle_check.speed_noise_rad_s = pll_quantisation_speed_noise_rad_s(angle.pll_bandwidth_rad_s, period_s, angle.encoder_bits);
  for (InjectionConfig* injection_config : {&injection, &calibration_injection}) {
    injection_config->lq_H = motor.lq_H;
    injection_config->lq_rated_H = motor.lq_rated_H;
    injection_config->lq_map = motor.lq_map;
    injection_config->rated_current_A = continuous_current_peak_A(motor);
    injection_config->ld_H = motor.ld_H;
    injection_config->rs_nominal_ohm = rs_seen_ohm;
    injection_config->flux_linkage_Wb = psi_Wb;
    injection_config->pole_pairs = motor.pole_pairs;
  }
  baseline.period_s = period_s;
  baseline.ld_H = motor.ld_H;
  baseline.pole_pairs = motor.pole_pairs;
  baseline.initial_rs_ohm = rs_seen_ohm;
  baseline.initial_ke_V_s_per_rad = emf_constant_dq_V_s_per_rad(motor);
}

DriveConfig with_motor_derived(DriveConfig config) {
  config.derive_from_motor();
  return config;
}

}  // namespace pmsm::core
