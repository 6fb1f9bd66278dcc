// A PI controller with the time step passed in and conditional-integration anti-windup.
#pragma once

#include <algorithm>

namespace pmsm::core {

struct PiGains {
  double kp = 0.0;
  double ki_per_s = 0.0;  // integral gain: output units per (error unit * second)
};

class PiController {
 public:
  PiController() = default;
  explicit PiController(const PiGains& gains) : gains_(gains) {}

  void set_gains(const PiGains& gains) { gains_ = gains; }
  [[nodiscard]] const PiGains& gains() const { return gains_; }

  void reset(double integral = 0.0) { integral_ = integral; }
  [[nodiscard]] double integral() const { return integral_; }

  // Returns the unclamped output kp * error + integral (+ feed_forward). The caller applies
  // its own limit (which may couple several controllers, as the dq voltage circle does) and
  // reports back the value actually used through limit_to().
  [[nodiscard]] double update(double error, double dt_s) {
    last_increment_ = gains_.ki_per_s * error * dt_s;
    integral_ += last_increment_;
    return gains_.kp * error + integral_;
  }

  // Conditional integration: after the caller limited the total output to `limited_output`,
  // take back this period's integration if it pushed further into the limit. Only the
  // increment is undone: removing the whole excess would also remove what a large
  // proportional term caused and leave the integral short after every step, to recover at
  // the slow rate of the PI zero.
  void limit_to(double limited_output, double unlimited_output) {
    (void)hold(unlimited_output - limited_output);
  }

  // The loop below could not follow the output (it saturated on a limit this controller does
  // not see, as a current loop on the voltage limit): take back this period's integration if
  // it pushed the output further in `direction`'s sign. Returns what was taken back (0 if
  // nothing), for the caller to take off the output it already has.
  [[nodiscard]] double hold(double direction) {
    const double taken = direction * last_increment_ > 0.0 ? last_increment_ : 0.0;
    integral_ -= taken;
    last_increment_ -= taken;
    return taken;
  }

  // Convenience for a stand-alone loop with a symmetric or asymmetric clamp.
  [[nodiscard]] double update_clamped(double error, double dt_s, double feed_forward, double lo,
                                      double hi) {
    const double unlimited = update(error, dt_s) + feed_forward;
    const double limited = std::clamp(unlimited, lo, hi);
    limit_to(limited, unlimited);
    return limited;
  }

 private:
  PiGains gains_{};
  double integral_ = 0.0;
  double last_increment_ = 0.0;
};

}  // namespace pmsm::core
