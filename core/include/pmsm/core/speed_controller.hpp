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
