// One robot's grid SLAM: MRPT's Rao-Blackwellized particle filter (CParticleFilter over
// CMultiMetricMapPDF, a grid per particle) with the optimal proposal (pfOptimalProposal: each
// particle's pose drawn around a scan match against its own grid, weighed with the odometry,
// Grisetti, Stachniss and Burgard 2007, the algorithm gmapping implements), fed the way
// slam_gmapping feeds its filter: gmapping's update rule picks the scans, the odometry since the
// last processed scan is the action. No ROS here: rbpf_slam (live) and rbpf_slam_replay (a bag,
// every scan) wrap it.
#pragma once

#include <mrpt/maps/COccupancyGridMap2D.h>
#include <mrpt/obs/CObservation2DRangeScan.h>
#include <mrpt/poses/CPose2D.h>
#include <mrpt/bayes/CParticleFilter.h>
#include <mrpt/obs/CActionRobotMovement2D.h>

#include "gyro_scale.h"

#include <cmath>
#include <cstdint>
#include <memory>

namespace rbpf_slam
{
class ScanMatchParticles;

/** The filter's settings, named and meant as slam_gmapping's parameters of the same name. */
struct Options
{
	int particles = 30;	 //!< particles of the filter
	double delta = 0.05;  //!< m per cell
	double xmin = -10, ymin = -10, xmax = 10, ymax = 10;  //!< initial map, m (it grows as needed)
	double maxUrange = 3.0;	 //!< m of each beam inserted into the map
	double maxRange = 8.0;	//!< m: a beam at or beyond it is no reading
	double linearUpdate = 1.0;	//!< m travelled (summed scan to scan) before a scan is processed
	double angularUpdate = 0.5;	 //!< rad turned (summed) before a scan is processed
	double temporalUpdate = -1.0;  //!< s since the last processed scan that also processes one; < 0: never
	// odometry error model, as gmapping's: srr translation from translation, srt translation
	// from rotation, str rotation from translation, stt rotation from rotation
	double srr = 0.1, srt = 0.2, str = 0.1, stt = 0.2;
	// the least spread of the odometry's step, however short (MRPT's minStdXY, minStdPHI): m, rad
	double minStdXY = 0.01, minStdYaw = 0.2 * M_PI / 180.0;
	double sigma = 0.05;  //!< m: the scan likelihood's standard deviation (gmapping's sigma)
	// a particle's scan match below this goodness (share of the scan's points matched, 0..1)
	// is not trusted: the odometry places it instead
	double matchMinGoodness = 0.7;
	double matchSearchRadius = 0.3;	 //!< m: how far a scan point first looks for a wall of the grid
	int seed = 0;  //!< the filter's random seed; 0: from the clock
	GyroScaleOptions gyroScale;  //!< the odometry heading's scale factor, learned from the scan matches
};

/** A robot's map frame pose (x, y m, yaw rad) and grid, after the scans offered so far. */
class RbpfMapper
{
   public:
	explicit RbpfMapper(const Options& options);
	~RbpfMapper();

	/** Offers one scan (stamp in s; odom: the base's odometry pose when the scan was taken;
	 * scan: in the base frame, its sensorPose set). Returns true when gmapping's update rule
	 * selected it and the filter processed it (the first scan always). */
	bool offer(double stamp, const mrpt::poses::CPose2D& odom, const mrpt::obs::CObservation2DRangeScan& scan);

	/** Scans offered (every one reaches the update rule), and those processed. */
	std::uint64_t received() const { return received_; }
	std::uint64_t processed() const { return processed_; }
	/** Particle moves so far placed by their scan match, and by the odometry (a poor match, or
	 * one the odometry could not have reached). */
	std::uint64_t matchedMoves() const;
	std::uint64_t odometryMoves() const;

	/** The base's pose in the map frame by the most likely particle, at the last processed scan. */
	mrpt::poses::CPose2D bestPose() const;
	/** The odometry pose of the last processed scan (bestPose's counterpart in the odom frame). */
	const mrpt::poses::CPose2D& lastProcessedOdom() const { return lastOdom_; }
	/** The most likely particle's grid; nullptr before the first processed scan. */
	const mrpt::maps::COccupancyGridMap2D* bestGrid() const;
	/** The odometry heading's scale factor: the one applied to the odometry's turns, its
	 * estimate, the steps it learned from (`~gyro_scale_learning`; factor 1 when off). */
	const GyroScaleEstimator& gyroScale() const { return gyroScale_; }

   private:
	Options options_;
	mrpt::bayes::CParticleFilter filter_;  //!< one step per processed scan: proposal, weights, resampling
	std::unique_ptr<ScanMatchParticles> particles_;
	mrpt::obs::CActionRobotMovement2D::TMotionModelOptions motion_;
	GyroScaleEstimator gyroScale_;
	std::uint64_t received_ = 0, processed_ = 0;
	// the update rule's state: odometry of the previous scan, distance and turn summed since
	// the last processed scan, its stamp and odometry
	mrpt::poses::CPose2D prevOdom_, lastOdom_;
	double linearSum_ = 0, angularSum_ = 0, lastStamp_ = 0;
};

/** An occupancy grid as slam_gmapping publishes one: row-major from the lower-left cell, -1
 * unknown (never observed), 0 free, 100 occupied (occupancy above one half). */
void gridToRos(const mrpt::maps::COccupancyGridMap2D& grid, std::int8_t* out);

}  // namespace rbpf_slam
