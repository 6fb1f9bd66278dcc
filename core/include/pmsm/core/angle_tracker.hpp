// Rotor angle and speed from an absolute encoder.
//
// The electrical angle used for the Park transform is the encoder reading itself (no lag);
// the speed comes from a type-2 phase-locked loop on the mechanical angle, which follows
// constant acceleration without a steady-state error. An unbiased speed matters here more
// than usual: the modulator advances the angle by 1.5 periods of rotation to cover the
// computation and PWM delay, and any bias in that advance rotates the voltage frame and
// leaks w Ld dId into the d-axis, where the resistive signal lives (docs/estimator.md).
#pragma once

#include <cstdint>

namespace pmsm::core {

struct AngleTrackerConfig {
  int encoder_bits = 14;
  int pole_pairs = 3;
  double electrical_offset_rad = 0.0;  // electrical angle at the lower edge of encoder count 0 (commissioned)
  // Where the rotor lies, on average, inside the interval of angles that reads one count, in
  // counts from the count's lower edge: 0.5 for an encoder that truncates (count = floor of
  // angle / resolution: the angle is then anywhere in [n, n + 1) counts), 0 for one that
  // rounds. Taking count n as angle n alone leaves the drive half a count behind the rotor on
  // average: see docs/estimator.md, "The encoder's half count".
  double count_centre = 0.5;
  double pll_bandwidth_rad_s = 300.0;
  double period_s = 1e-4;
};

class AngleTracker {
 public:
  explicit AngleTracker(const AngleTrackerConfig& config);

  // One sample of the encoder.
  void update(std::uint32_t encoder_count);
  // Samples lost before the next update (`periods` of them, the power stage running on): the
  // loop's prediction for the next sample runs on over them. Once the speed is known.
  void skip(std::uint32_t periods) {
    pll_theta_rad_ += speed_m_rad_s_ * config_.period_s * static_cast<double>(periods);
  }

  [[nodiscard]] double mechanical_angle_rad() const { return theta_m_rad_; }   // [0, 2 pi)
  [[nodiscard]] double electrical_angle_rad() const { return theta_e_rad_; }   // [0, 2 pi)
  // Electrical angle accumulated since start (not wrapped): what recordings measure arcs in.
  [[nodiscard]] double unwrapped_electrical_angle_rad() const { return unwrapped_e_rad_; }
  // The PLL's electrical angle, unwrapped: smooth and monotonic at speed, which is what
  // matching recordings by angle needs (the raw encoder angle steps in counts).
  [[nodiscard]] double smooth_unwrapped_electrical_angle_rad() const {
    return config_.pole_pairs * smooth_m_rad_ + offset_rad_;
  }
  // A correction of the commissioned offset measured since (the calibration's angle check,
  // angle_check.hpp, or a stored calibration's): added to electrical_offset_rad from the next
  // sample on. The angles jump by the change of it.
  void set_offset_correction_rad(double correction_rad) {
    correction_rad_ = correction_rad;
    offset_rad_ = config_.electrical_offset_rad + correction_rad;
    electrical_base_rad_ = electrical_base_rad();
  }
  [[nodiscard]] double offset_correction_rad() const { return correction_rad_; }
  // The electrical angle the encoder turned through since the previous sample (0 at the first
  // sample after a reset): divided by the period, the period's mean speed. Unlike the PLL's
  // speed it does not lag a speed transient inside a pair's recording (the injection's own
  // torque makes one on a light rotor); its quantization telescopes over a recording.
  [[nodiscard]] double last_step_electrical_rad() const { return last_step_e_rad_; }
  [[nodiscard]] double mechanical_speed_rad_s() const { return speed_m_rad_s_; }
  [[nodiscard]] double electrical_speed_rad_s() const { return speed_m_rad_s_ * config_.pole_pairs; }
  [[nodiscard]] bool initialised() const { return initialised_; }
  // Whether the speed is the rotor's: from the second sample after a start or a reset(), when
  // the loop takes the encoder's advance over that period as its speed (rather than
  // acquiring it from zero, which at speed reads thousands of rad/s off for milliseconds).
  [[nodiscard]] bool speed_known() const { return speed_known_; }

  void reset();

 private:
  AngleTrackerConfig config_;
  double correction_rad_ = 0.0;
  // The electrical angle of a count's centre less that of its lower edge, plus the offset,
  // wrapped into a turn: the electrical angle is then (count x pole pairs mod a turn) counts
  // plus this, less a turn when it passes one (update).
  [[nodiscard]] double electrical_base_rad() const;

  double offset_rad_;              // the commissioned offset plus the correction
  double counts_to_rad_;
  double kp_;
  double ki_;
  double electrical_base_rad_;
  bool initialised_ = false;
  bool speed_known_ = false;
  double theta_m_rad_ = 0.0;
  double theta_e_rad_ = 0.0;
  double previous_theta_m_rad_ = 0.0;
  double unwrapped_e_rad_ = 0.0;
  double last_step_e_rad_ = 0.0;
  double pll_theta_rad_ = 0.0;   // the PLL's prediction for the next sample (unwrapped, mechanical)
  double smooth_m_rad_ = 0.0;    // its estimate for the present sample
  double integrator_m_rad_s_ = 0.0;
  double pll_measured_unwrapped_rad_ = 0.0;
  double speed_m_rad_s_ = 0.0;
};

}  // namespace pmsm::core
