// What rbpf_slam (live) and rbpf_slam_replay (a bag) share of ROS: the filter's settings from
// the private parameters (gmapping's names), a scan as MRPT's observation, poses from TF, and
// the grid as an OccupancyGrid.
#pragma once

#include "rbpf_mapper.h"

#include <geometry_msgs/Transform.h>
#include <mrpt/poses/CPose3D.h>
#include <nav_msgs/OccupancyGrid.h>
#include <ros/ros.h>
#include <sensor_msgs/LaserScan.h>

#include <string>

namespace rbpf_slam
{
/** The frames and the filter's settings from the private parameters (`pnh`: the node's "~").
 * A value out of range is logged as one error naming the parameter, and its default used. */
struct NodeSettings
{
	std::string baseFrame, odomFrame, mapFrame;
	Options filter;
	double mapUpdateInterval = 5.0;	 //!< s of scan time between published maps
	double transformPublishPeriod = 0.05;  //!< s between map -> odom transforms; 0: none
};
NodeSettings readSettings(ros::NodeHandle& pnh);

/** A scan as MRPT's observation, in the base frame (`laser`: the laser's pose on the base); a
 * reading at or beyond `maxRange` is no reading. False when it cannot be converted. */
bool toObservation(
	const sensor_msgs::LaserScan& scan, const mrpt::poses::CPose3D& laser, double maxRange,
	mrpt::obs::CObservation2DRangeScan& out);

/** A TF transform as a 3D pose, and as a planar one (x, y, yaw). */
mrpt::poses::CPose3D pose3D(const geometry_msgs::Transform& t);
mrpt::poses::CPose2D pose2D(const geometry_msgs::Transform& t);

/** The grid as slam_gmapping publishes it, in `frame`, stamped `stamp`. */
nav_msgs::OccupancyGrid gridMessage(
	const mrpt::maps::COccupancyGridMap2D& grid, const std::string& frame, const ros::Time& stamp);

}  // namespace rbpf_slam
