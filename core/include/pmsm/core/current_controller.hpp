// The rotor-frame current controller: d and q PI controllers with decoupling feed-forward
// (the w L i cross terms and the EMF of Eq. 3), and a voltage limit that keeps the command
// inside the modulator's linear range.
//
// Gains follow the usual pole-zero cancellation (Kp = wc L, Ki = wc Rs), so the closed loop
// behaves as a first-order lag with bandwidth wc, delayed by the 1.5 periods of computation
// and PWM averaging; wc well below 1/(1.5 Ts) keeps the phase margin high.
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
  // Usable fraction of the linear modulation limit Vdc / sqrt(3) (the circle inscribed in
  // the SVPWM hexagon); a little margin leaves room for dead-time compensation.
  double voltage_limit_fraction = 0.95;
};

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

  // Voltage limit for a DC-bus voltage (radius of the usable circle).
  [[nodiscard]] double voltage_limit_V(double vdc_V) const;

 private:
  CurrentControllerConfig config_;
  PiController pi_d_;
  PiController pi_q_;
  CurrentControllerStatus status_{};
};

}  // namespace pmsm::core
