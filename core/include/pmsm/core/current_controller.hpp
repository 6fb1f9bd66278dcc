// The rotor-frame current controller: d and q PI controllers with decoupling feed-forward
// (the w L i cross terms and the EMF of Eq. 3), and a voltage limit that keeps the command
// inside the modulator's linear range.
//
// Kp = wc L sets the crossover at wc. The integral zero sits at max(Rs/L, zero_fraction wc):
// pole-zero cancellation (zero at Rs/L, about 24 rad/s for Table I) would give a clean
// first-order step response but rejects a disturbance only at that slow rate, and the
// decoupling of a commissioned (not exact) machine leaves disturbances: a 10 % Ld error
// puts w dLd dId on the q-axis at every injection edge, which would then sag iq and the
// torque for tens of milliseconds. A zero at 0.1 wc rejects it eight times faster at the
// cost of a few per cent of overshoot.
#pragma once

#include "pmsm/core/pi_controller.hpp"
#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

struct CurrentControllerConfig {
  double period_s = 1e-4;
  double bandwidth_rad_s = 2000.0;
  // The controller's own model of the machine (as commissioned; need not equal the truth).
  double rs_ohm = 0.133;
  double ld_H = 5.5e-3;
  double lq_H = 5.5e-3;
  double flux_linkage_Wb = 0.3239;
  bool decoupling = true;
  double integral_zero_fraction = 0.1;  // integral zero at this fraction of the bandwidth (at least Rs/L)
  // Usable fraction of the linear modulation limit Vdc / sqrt(3) (the circle inscribed in
  // the SVPWM hexagon); a little margin leaves room for dead-time compensation.
  double voltage_limit_fraction = 0.95;
};

// Voltage limit for a DC-bus voltage (radius of the usable circle).
[[nodiscard]] constexpr double voltage_limit_V(const CurrentControllerConfig& config, double vdc_V) {
  return config.voltage_limit_fraction * vdc_V / kSqrt3;
}

struct CurrentControllerStatus {
  Dq v_V{};                 // the command after limiting
  Dq v_unlimited_V{};       // before limiting
  bool voltage_limited = false;
  double voltage_limit_V = 0.0;
};

class CurrentController {
 public:
  explicit CurrentController(const CurrentControllerConfig& config);

  // One control period. `omega_e` is the electrical speed, `vdc` the measured DC-bus voltage.
  const CurrentControllerStatus& step(const Dq& i_ref_A, const Dq& i_meas_A,
                                      double omega_e_rad_s, double vdc_V);

  void reset();
  [[nodiscard]] const CurrentControllerConfig& config() const { return config_; }
  [[nodiscard]] const CurrentControllerStatus& status() const { return status_; }

  // The voltage limit for a DC-bus voltage (the free function). Inline: asked twice a period.
  [[nodiscard]] double voltage_limit_V(double vdc_V) const { return core::voltage_limit_V(config_, vdc_V); }

 private:
  CurrentControllerConfig config_;
  PiController pi_d_;
  PiController pi_q_;
  CurrentControllerStatus status_{};
};

}  // namespace pmsm::core
