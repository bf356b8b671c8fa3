#include "gyro_scale.h"

#include <algorithm>
#include <cstdio>

namespace rbpf_slam
{
double GyroScaleEstimator::estimate() const
{
	// y = k x + n, n ~ N(0, s^2), k ~ N(1, p^2): the posterior's mean is
	// (sum xy / s^2 + 1 / p^2) / (sum xx / s^2 + 1 / p^2)
	const double prior = (kStepSigma * kStepSigma) / (options_.priorSigma * options_.priorSigma);
	const double k = (sumXY_ + prior) / (sumXX_ + prior);
	return std::clamp(k, 1.0 - options_.limit, 1.0 + options_.limit);
}

bool GyroScaleEstimator::addStep(double odometryTurn, double matchTurn)
{
	if (!options_.enabled || !std::isfinite(odometryTurn) || !std::isfinite(matchTurn)) return false;
	// a true factor within the limit keeps the match's turn within limit * |x| of the odometry's,
	// plus the match's noise: further out, the match is wrong (a wall mistaken for another)
	const double gate = options_.limit * std::abs(odometryTurn) + 4.0 * kStepSigma;
	if (std::abs(matchTurn - odometryTurn) > gate)
	{
		++rejected_;
		return false;
	}
	++used_;
	sumXY_ += odometryTurn * matchTurn;
	sumXX_ += odometryTurn * odometryTurn;
	turnUsed_ += std::abs(odometryTurn);
	turnSinceUpdate_ += std::abs(odometryTurn);
	if (turnSinceUpdate_ < options_.window) return false;
	// the rest carries over: one update per window of turn however the steps fall
	turnSinceUpdate_ = std::fmod(turnSinceUpdate_, options_.window);
	++updates_;
	const double before = applied_;
	applied_ = estimate();
	return applied_ != before;
}

std::string GyroScaleEstimator::summary() const
{
	if (!options_.enabled) return "gyro scale learning off";
	char line[200];
	std::snprintf(
		line, sizeof line,
		"gyro scale %.4f applied, estimate %.4f, from %llu steps (%.0f deg of odometry turn), %llu left out, %llu "
		"updates",
		applied_, estimate(), static_cast<unsigned long long>(used_), turnUsed_ * 180.0 / M_PI,
		static_cast<unsigned long long>(rejected_), static_cast<unsigned long long>(updates_));
	return line;
}

}  // namespace rbpf_slam
