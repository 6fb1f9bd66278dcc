// The boundary between the wire and the controller: ADC codes and encoder counts in, duty
// cycles out, with the controller's own (nominal) scaling and the current-ADC offset
// calibration every drive does at power-up with its gates off.
#pragma once

#include <array>
#include <cstdint>

#include "controller_config.hpp"
#include "pmsm/core/drive_controller.hpp"
#include "pmsm/hal/messages.hpp"

namespace pmsm::app {

class SensorFrontend {
 public:
  SensorFrontend(const SensorScaling& scaling, double period_s);

  // Converts one sample. While the offset calibration runs (the first offset_calibration_s
  // with the gates off), the codes are averaged and the input is marked not ready.
  [[nodiscard]] core::DriveInput convert(const hal::SensorSample& sample);

  // Duties and enable for the period after `sample`.
  [[nodiscard]] static hal::InverterCommand command(const core::DriveOutput& out, std::uint32_t sequence);

  [[nodiscard]] bool ready() const { return calibrated_; }
  [[nodiscard]] const std::array<double, 3>& offsets_A() const { return offsets_A_; }
  // The current samples' noise (standard deviation, A): sensors.current_noise_A when
  // configured, else measured with the offsets (gates off: what varies is the sensor) from the
  // differences of consecutive samples of each phase (half their mean square, the three
  // phases averaged), so that a current still decaying through the diodes when the gates went
  // off does not count as noise: a difference above 32 ADC steps is not noise and is left
  // out. 0 before the offsets are known, without an offset calibration, or from fewer than
  // 100 differences.
  [[nodiscard]] double current_noise_A() const { return noise_A_; }

 private:
  double current_lsb_A_;
  double dc_lsb_V_;
  int calibration_samples_;
  int collected_ = 0;
  bool calibrated_ = false;
  std::array<double, 3> sums_{};
  std::array<double, 3> previous_A_{};
  bool have_previous_ = false;
  double difference_squares_ = 0.0;
  int differences_ = 0;
  double noise_A_ = 0.0;
  bool noise_configured_ = false;
  std::array<double, 3> offsets_A_{};
};

}  // namespace pmsm::app
