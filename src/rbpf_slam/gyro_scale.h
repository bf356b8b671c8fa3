// The scale factor of a robot's odometry heading, learned from the filter's own scan matches.
// A Turtlebot3 Burger's odometry heading is its gyro's (MPU-9250, scale tolerance 3 %): the turn
// it reports is the true turn times one fixed factor for the robot's whole run, so every turn
// errs the same way. MRPT's motion model gives each step's turn an error of its own; this
// estimates the factor itself, and the mapper multiplies the odometry's turns by it before they
// enter the filter. No MRPT, no ROS here, so the estimator is checked on its own
// (test/unit/rbpf/test_gyro_scale.py drives gyro_scale_check.cpp).
#pragma once

#include <cmath>
#include <cstdint>
#include <string>

namespace rbpf_slam
{
/** The estimator's settings (rbpf_slam's `~gyro_scale_*` parameters). */
struct GyroScaleOptions
{
	bool enabled = false;  //!< learn the scale and apply it; false: the odometry's turns as they are
	double limit = 0.05;  //!< the learned factor stays within 1 +- limit (a Burger's gyro: 3 % tolerance)
	double window = M_PI / 2;  //!< rad of odometry turn between two updates of the factor applied
	double priorSigma = 0.01;  //!< the spread of a gyro's scale error before any turn is seen (1 sigma)
};

/** The factor k that maps the odometry's turn onto the true one (true turn = k * odometry turn),
 * as the maximum a posteriori estimate over every step seen: each processed step gives the
 * odometry's own turn x (before any factor) and the scan match's turn y over the same step, y =
 * k x + noise (noise: `kStepSigma` a step), with the prior k ~ N(1, priorSigma^2). A step whose
 * match turn is further from its odometry's than the limit and 4 sigma of the noise allow is a
 * poor match, and left out. The factor applied moves only at the end of a window of `window` rad
 * of odometry turn: a few steps of a spin are too few to tell the scale from the match's noise,
 * and the applied factor should not chatter. */
class GyroScaleEstimator
{
   public:
	/** The noise of one step's scan-match turn, rad: the match's own floor (0.5 degree) and the
	 * spread of the pose it started from. */
	static constexpr double kStepSigma = 0.01;

	explicit GyroScaleEstimator(const GyroScaleOptions& options) : options_(options) {}

	/** One processed step: the odometry's turn (rad, raw, no factor applied) and the scan match's
	 * turn over the same step (rad). Returns true when the factor applied changed. */
	bool addStep(double odometryTurn, double matchTurn);

	/** The factor applied to the odometry's turns now (1 until the first window closes, or
	 * when disabled). */
	double scale() const { return applied_; }
	/** The current estimate (the applied one lags it by up to a window). */
	double estimate() const;
	/** Steps used, steps left out as poor matches, and updates of the factor applied. */
	std::uint64_t stepsUsed() const { return used_; }
	std::uint64_t stepsRejected() const { return rejected_; }
	std::uint64_t updates() const { return updates_; }
	/** rad of odometry turn in the steps used, in all. */
	double turnUsed() const { return turnUsed_; }

	const GyroScaleOptions& options() const { return options_; }
	/** One line for the node's log: the factor applied, the estimate, what it learned from. */
	std::string summary() const;

   private:
	GyroScaleOptions options_;
	double sumXY_ = 0, sumXX_ = 0;  //!< rad^2: sums of odometry turn x match turn, odometry turn squared
	double turnUsed_ = 0, turnSinceUpdate_ = 0;  //!< rad of odometry turn (absolute)
	double applied_ = 1.0;
	std::uint64_t used_ = 0, rejected_ = 0, updates_ = 0;
};

}  // namespace rbpf_slam
