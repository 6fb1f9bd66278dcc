// The speed loop above the current loop: a PI on mechanical speed producing a torque demand,
// run at a lower rate (every `decimation` current-loop periods), and the conversion of the
// torque demand into a q-axis current reference within the current limit.
#pragma once

#include "pmsm/core/pi_controller.hpp"

namespace pmsm::core {

struct SpeedControllerConfig {
  double period_s = 1e-3;             // the speed loop's own period
  double bandwidth_rad_s = 60.0;      // closed-loop speed bandwidth
  double inertia_kg_m2 = 0.00841;     // the controller's estimate of the total inertia
  double integral_ratio = 0.2;        // PI zero at integral_ratio * bandwidth
  double max_torque_Nm = 100.0;
};

// The PLL's speed noise from the encoder's rounding alone, RMS rad/s. An encoder of b bits reads
// the angle to a count q = 2 pi / 2^b; turning, its rounding error is uniform over the count and
// nearly white from one sample to the next: q / sqrt(12) RMS. The PLL (angle_tracker.hpp,
// kp = 2 wn, ki = wn^2 on the sampled angle) passes it to its speed with the gain of its
// proportional path, 2 wn, and a little more from the loop's own dynamics: the l2 norm of its
// discrete impulse response is 2 wn (1 + wn T) to 0.3 % for wn T up to 0.1. (Sample to sample,
// not independent: the speed is the step of the PLL's own angle, so its average over a span is
// the span's angle error over its length, bounded.)
[[nodiscard]] double pll_quantisation_speed_noise_rad_s(double pll_bandwidth_rad_s, double period_s, int encoder_bits);

// The speed loop's answer to the encoder's resolution: its proportional gain, J x its bandwidth,
// turns the speed noise above into torque demand, the RMS returned here. (The integral's share is
// integral_ratio (wc T_speed) of it, and the current loop passes the rest to the shaft.) A
// 12.6 kg m^2 centrifuge with a 14-bit encoder, the default 60 rad/s and the PLL's 300 rad/s:
// 52 N m RMS on a 99 N m motor, and braking it tripped on overcurrent (docs/daemon.md, "The speed
// loop and the encoder").
[[nodiscard]] double speed_loop_quantisation_torque_Nm(double inertia_kg_m2, double bandwidth_rad_s,
                                                       double pll_bandwidth_rad_s, double period_s,
                                                       int encoder_bits);

// The bandwidth at which speed_loop_quantisation_torque_Nm() is `torque_rms_Nm` (it is
// proportional to the bandwidth).
[[nodiscard]] double speed_bandwidth_for_quantisation_torque_rad_s(double torque_rms_Nm, double inertia_kg_m2,
                                                                   double pll_bandwidth_rad_s, double period_s,
                                                                   int encoder_bits);

class SpeedController {
 public:
  explicit SpeedController(const SpeedControllerConfig& config);

  // One speed-loop period; returns the torque demand, limited to +-max_torque (or to the
  // tighter limit given, e.g. from the derated current limit).
  // `current_loop_saturated`: the current loop was on its voltage limit since the last call,
  // so the torque asked was not all delivered. The integral then does not grow the demand
  // further (conditional integration on a limit outside this loop): without this, a drive held
  // below its set-point by the voltage limit winds its integral up, and the first moment of
  // headroom (a field-weakening injection pulse, a lighter load) releases it as a speed
  // overshoot far beyond the set-point.
  // `feed_forward_Nm` is added to the PI's output inside the limit (e.g. J x the reference's
  // slope).
  double step(double speed_ref_rad_s, double speed_meas_rad_s, double torque_limit_Nm,
              bool current_loop_saturated = false, double feed_forward_Nm = 0.0);

  void reset(double torque_Nm = 0.0) { pi_.reset(torque_Nm); }
  [[nodiscard]] const SpeedControllerConfig& config() const { return config_; }

 private:
  SpeedControllerConfig config_;
  PiController pi_;
};

}  // namespace pmsm::core
