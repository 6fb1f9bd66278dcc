#include "sensor_frontend.hpp"

#include <algorithm>
#include <cmath>

namespace pmsm::app {

SensorFrontend::SensorFrontend(const SensorScaling& scaling, double period_s)
    : current_lsb_A_(scaling.current_range_A / std::ldexp(1.0, scaling.current_adc_bits - 1)),
      dc_lsb_V_(scaling.dc_bus_full_scale_V / std::ldexp(1.0, scaling.dc_bus_adc_bits)),
      calibration_samples_(static_cast<int>(std::lround(scaling.offset_calibration_s / period_s))),
      calibrated_(calibration_samples_ <= 0) {
  if (scaling.current_noise_A) {
    noise_A_ = *scaling.current_noise_A;
    noise_configured_ = true;
  }
}

core::DriveInput SensorFrontend::convert(const hal::SensorSample& sample) {
  core::DriveInput in;
  std::array<double, 3> i{};
  for (std::size_t n = 0; n < 3; ++n) {
    i[n] = sample.phase_current_adc[n] * current_lsb_A_;
  }
  if (!calibrated_) {
    // Gates off: whatever the ADCs read is their offset (plus noise, averaged away).
    if ((sample.flags & hal::kSensorOutputEnabled) == 0U) {
      for (std::size_t n = 0; n < 3; ++n) {
        sums_[n] += i[n];
        const double d = i[n] - previous_A_[n];
        if (have_previous_ && std::abs(d) <= 32.0 * current_lsb_A_) {
          difference_squares_ += d * d;
          ++differences_;
        }
        previous_A_[n] = i[n];
      }
      have_previous_ = true;
      ++collected_;
    } else {
      have_previous_ = false;  // differences only between consecutive gates-off samples
    }
    if (collected_ >= calibration_samples_) {
      for (std::size_t n = 0; n < 3; ++n) {
        offsets_A_[n] = sums_[n] / collected_;
      }
      if (!noise_configured_ && differences_ >= 100) {
        // Var(x_k - x_k-1) = 2 sigma^2 for white noise.
        noise_A_ = std::sqrt(0.5 * difference_squares_ / differences_);
      }
      calibrated_ = true;
    }
  }
  in.i_A = {i[0] - offsets_A_[0], i[1] - offsets_A_[1], i[2] - offsets_A_[2]};
  in.encoder_count = sample.encoder_count;
  in.vdc_V = sample.dc_bus_adc * dc_lsb_V_;
  in.valid = calibrated_;
  return in;
}

hal::InverterCommand SensorFrontend::command(const core::DriveOutput& out, std::uint32_t sequence) {
  hal::InverterCommand c;
  c.sequence = sequence;
  const bool finite = std::isfinite(out.duty[0]) && std::isfinite(out.duty[1]) && std::isfinite(out.duty[2]);
  // A non-finite duty never becomes a plausible number (0 would switch every low side on):
  // the gates go off and the duties read zero.
  c.enable = out.enable && finite && !out.fault;
  if (!finite) {
    return c;
  }
  for (std::size_t n = 0; n < 3; ++n) {
    // Rounded half away from zero as std::lround does, without its libm call (about 27
    // instructions, three a period): the scaled duty is in [0, 65535], its fraction exact.
    const double scaled = std::clamp(out.duty[n], 0.0, 1.0) * hal::kDutyFullScale;
    auto counts = static_cast<std::uint16_t>(scaled);
    if (scaled - static_cast<double>(counts) >= 0.5) {
      ++counts;
    }
    c.duty[n] = counts;
  }
  return c;
}

}  // namespace pmsm::app
