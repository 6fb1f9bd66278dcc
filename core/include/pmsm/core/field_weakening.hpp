// Field weakening by voltage feedback: above the speed where the EMF and the motoring point's
// w L i take the whole voltage the bus allows, a negative d-axis current lowers the flux the
// stator sees (vq = w (psi + Ld id) + Rs iq, Eq. 3), so that the current loop keeps control of
// the current and the shaft goes on past the id = 0 speed.
//
// The regulator integrates the voltage margin: d(id)/dt = wfw (k Vlim - |v*|) / (|we| Ld),
// with |v*| the current controller's command before its limit and k Vlim the magnitude it is
// held at. Near the limit |v*| moves by about |we| Ld per ampere of id, so the loop closes at
// wfw whatever the speed (the gain is scheduled with it). Below the limit the margin is
// positive and id returns to zero: the regulator does nothing where it is not needed, and a
// drive below base speed runs id = 0 control (Eq. 10) as before. |id| stays within a bound
// (DriveConfig::field_weakening), so the current left for torque is sqrt(I^2 - id^2).
//
// The injection's pairs need the motoring point to hold still between their two recordings
// (the separation subtracts it): the caller holds the regulator while a pair runs.
#pragma once

namespace pmsm::core {

struct FieldWeakeningConfig {
  bool enabled = false;
  double max_current_A = 0.0;       // the largest |id| it may ask (peak A)
  double bandwidth_rad_s = 200.0;   // the voltage loop's
  // k: |v*| is held at this share of the current loop's limit. The rest is the loop's reserve
  // for what it cannot follow: on the Table I machine at 420 rad/s the EMF harmonics' current
  // ripple put the loop on its limit in a quarter of the periods at 0.95, in none at 0.9
  // (DriveNode.FieldWeakeningCarriesTheShaftPastTheIdZeroSpeed).
  double voltage_fraction = 0.9;
};

class FieldWeakening {
 public:
  explicit FieldWeakening(const FieldWeakeningConfig& config) : config_(config) {}

  // One control period. `v_command_V` is |v*| of the last period (before the limit),
  // `voltage_limit_V` that period's limit, `bound_A` the largest |id| allowed now (the tighter
  // of the configured one and the drive's current limit). Returns the d current to run (<= 0).
  double step(double v_command_V, double voltage_limit_V, double omega_e_rad_s, double bound_A);

  void reset() {
    id_A_ = 0.0;
    settled_ = true;
  }
  [[nodiscard]] double id_A() const { return id_A_; }
  // A pulse's d current that ends while the regulator is held (DriveController::weaken_field):
  // id takes it over where it weakens the field more, within the bounds of step(), so that the
  // d current does not step back and the regulator relaxes it from there.
  void take_over(double id_A, double bound_A);
  [[nodiscard]] double voltage_fraction() const { return config_.voltage_fraction; }
  // The voltage sits where the regulator holds it (within kSettledFraction of the limit), or id
  // rests on a bound the margin presses it against (zero below the field-weakening speed, the
  // largest |id| where even that is not enough): id will not move on its own.
  [[nodiscard]] bool settled() const { return settled_; }
  static constexpr double kSettledFraction = 0.02;
  [[nodiscard]] bool enabled() const { return config_.enabled; }
  // Integral gain per (V s) at electrical speed w: wfw / (max(|w|, w_floor) Ld), with the
  // floor a quarter of the speed where the EMF alone takes the limit (the gain stays finite
  // at standstill, where the margin is large and id is already zero).
  void set_machine(double ld_H, double flux_linkage_Wb, double period_s);

 private:
  FieldWeakeningConfig config_;
  double id_A_ = 0.0;
  bool settled_ = true;
  double gain_A_per_V_rad_ = 0.0;    // wfw T / Ld (divided by the speed at each step)
  double floor_per_V_ = 0.0;         // w_floor / Vlim = 1 / (4 psi)
};

}  // namespace pmsm::core
