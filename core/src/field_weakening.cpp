#include "pmsm/core/field_weakening.hpp"

#include <algorithm>
#include <cmath>

namespace pmsm::core {

void FieldWeakening::set_machine(double ld_H, double flux_linkage_Wb, double period_s) {
  gain_A_per_V_rad_ = config_.bandwidth_rad_s * period_s / ld_H;
  floor_per_V_ = 0.25 / flux_linkage_Wb;
}

double FieldWeakening::step(double v_command_V, double voltage_limit_V, double omega_e_rad_s, double bound_A) {
  if (!config_.enabled || !(voltage_limit_V > 0.0)) {
    reset();
    return id_A_;
  }
  const double speed = std::max(std::abs(omega_e_rad_s), floor_per_V_ * voltage_limit_V);
  const double margin_V = config_.voltage_fraction * voltage_limit_V - v_command_V;
  const double next = id_A_ + gain_A_per_V_rad_ * margin_V / speed;
  // Within [-bound, 0]; a bound that shrank (a derating) takes id with it. A NaN margin
  // (no voltage to read) leaves id where it was.
  const double lower = -std::min(config_.max_current_A, bound_A);
  id_A_ = std::clamp(std::isnan(next) ? id_A_ : next, lower, 0.0);
  settled_ = std::abs(margin_V) <= kSettledFraction * voltage_limit_V || (id_A_ == 0.0 && margin_V > 0.0) ||
             (id_A_ == lower && margin_V < 0.0);
  return id_A_;
}

void FieldWeakening::take_over(double id_A, double bound_A) {
  if (!config_.enabled || !(id_A < id_A_)) {
    return;  // (a NaN takes nothing over)
  }
  // (A bound that shrank below the present id is step()'s to apply, as a derating's.)
  id_A_ = std::min(id_A_, std::max(id_A, -std::min(config_.max_current_A, bound_A)));
  settled_ = false;
}

}  // namespace pmsm::core
