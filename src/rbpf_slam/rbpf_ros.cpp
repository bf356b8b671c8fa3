#include "rbpf_ros.h"

#include <mrpt/ros1bridge/time.h>
#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2/utils.h>

#include <algorithm>
#include <cmath>

namespace rbpf_slam
{
namespace
{
double number(ros::NodeHandle& nh, const std::string& name, double fallback, bool positive)
{
	double v = fallback;
	if (!nh.getParam(name, v)) return fallback;
	if (std::isfinite(v) && (!positive || v > 0)) return v;
	ROS_ERROR_STREAM(
		"~" << name << " = " << v << " is not " << (positive ? "a finite number above 0" : "a finite number")
			<< ": using " << fallback);
	return fallback;
}
}  // namespace

NodeSettings readSettings(ros::NodeHandle& pnh)
{
	NodeSettings s;
	s.baseFrame = pnh.param<std::string>("base_frame", "base_link");
	s.odomFrame = pnh.param<std::string>("odom_frame", "odom");
	s.mapFrame = pnh.param<std::string>("map_frame", "map");
	Options& o = s.filter;
	int particles = o.particles;
	if (pnh.getParam("particles", particles))
	{
		if (particles >= 1 && particles <= 10000) o.particles = particles;
		else ROS_ERROR("~particles = %d is not 1..10000: using %d", particles, o.particles);
	}
	o.delta = number(pnh, "delta", 0.05, true);
	o.maxRange = number(pnh, "maxRange", 8.0, true);
	o.maxUrange = std::min(number(pnh, "maxUrange", std::min(o.maxRange, 80.0), true), o.maxRange);
	o.linearUpdate = number(pnh, "linearUpdate", 1.0, false);
	o.angularUpdate = number(pnh, "angularUpdate", 0.5, false);
	o.temporalUpdate = number(pnh, "temporalUpdate", -1.0, false);
	o.xmin = number(pnh, "xmin", -10.0, false);
	o.ymin = number(pnh, "ymin", -10.0, false);
	o.xmax = number(pnh, "xmax", 10.0, false);
	o.ymax = number(pnh, "ymax", 10.0, false);
	if (o.xmax <= o.xmin || o.ymax <= o.ymin)
	{
		ROS_ERROR("~xmin..~xmax, ~ymin..~ymax is an empty map: using -10..10 m for both");
		o.xmin = o.ymin = -10;
		o.xmax = o.ymax = 10;
	}
	o.srr = number(pnh, "srr", 0.1, false);
	o.srt = number(pnh, "srt", 0.2, false);
	o.str = number(pnh, "str", 0.1, false);
	o.stt = number(pnh, "stt", 0.2, false);
	o.minStdXY = number(pnh, "min_std_xy", o.minStdXY, true);
	o.minStdYaw = number(pnh, "min_std_yaw", o.minStdYaw, true);
	o.sigma = number(pnh, "sigma", 0.05, true);
	o.matchMinGoodness = number(pnh, "match_min_goodness", 0.7, false);
	o.matchSearchRadius = number(pnh, "match_search_radius", 0.3, true);
	o.seed = pnh.param<int>("seed", 0);
	GyroScaleOptions& g = o.gyroScale;
	g.enabled = pnh.param<bool>("gyro_scale_learning", g.enabled);
	g.limit = number(pnh, "gyro_scale_limit", g.limit, true);
	if (g.limit >= 0.5)
	{
		ROS_ERROR("~gyro_scale_limit = %g is not under 0.5: using 0.05", g.limit);
		g.limit = 0.05;
	}
	g.window = number(pnh, "gyro_scale_window", g.window, true);
	g.priorSigma = number(pnh, "gyro_scale_prior_sigma", g.priorSigma, true);
	s.mapUpdateInterval = number(pnh, "map_update_interval", 5.0, false);
	s.transformPublishPeriod = number(pnh, "transform_publish_period", 0.05, false);
	return s;
}

bool toObservation(
	const sensor_msgs::LaserScan& scan, const mrpt::poses::CPose3D& laser, double maxRange,
	mrpt::obs::CObservation2DRangeScan& out)
{
	// MRPT spreads a scan's N beams evenly over its aperture, centred on the sensor's x axis.
	// Beam i of the ROS scan is at angle_min + i * angle_increment: so the aperture is
	// (N - 1) increments and the sensor turned to the scan's middle angle, beams in their own
	// order. (mrpt::ros1bridge::fromROS instead maps each MRPT beam to a ROS index by truncation,
	// which can put a beam one increment off.)
	const size_t n = scan.ranges.size();
	if (n < 2 || !std::isfinite(scan.angle_increment) || scan.angle_increment == 0.0f) return false;
	const double increment = std::abs(static_cast<double>(scan.angle_increment));
	const double aperture = increment * static_cast<double>(n - 1);
	const double first = scan.angle_increment > 0 ? scan.angle_min : scan.angle_min + scan.angle_increment * (n - 1.0);
	const double middle = first + 0.5 * aperture;
	out = mrpt::obs::CObservation2DRangeScan();
	out.timestamp = mrpt::ros1bridge::fromROS(scan.header.stamp);
	out.sensorLabel = scan.header.frame_id;
	out.rightToLeft = true;
	out.aperture = static_cast<float>(aperture);
	const double usable = std::min<double>(scan.range_max, maxRange);
	out.maxRange = static_cast<float>(usable);
	out.sensorPose = laser + mrpt::poses::CPose3D(0, 0, 0, middle, 0, 0);
	out.resizeScan(n);
	for (size_t i = 0; i < n; ++i)
	{
		const float r = scan.ranges[scan.angle_increment > 0 ? i : n - 1 - i];
		// as gmapping: no reading (inf, NaN, 0 or under range_min) and readings at or beyond
		// maxRange are no obstacle
		const bool valid = std::isfinite(r) && r > scan.range_min && r < usable;
		out.setScanRange(i, valid ? r : static_cast<float>(usable));
		out.setScanRangeValidity(i, valid);
	}
	return true;
}

mrpt::poses::CPose3D pose3D(const geometry_msgs::Transform& t)
{
	double roll, pitch, yaw;
	tf2::Matrix3x3(tf2::Quaternion(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)).getRPY(roll, pitch, yaw);
	return mrpt::poses::CPose3D(t.translation.x, t.translation.y, t.translation.z, yaw, pitch, roll);
}

mrpt::poses::CPose2D pose2D(const geometry_msgs::Transform& t)
{
	return mrpt::poses::CPose2D(t.translation.x, t.translation.y, tf2::getYaw(t.rotation));
}

nav_msgs::OccupancyGrid gridMessage(
	const mrpt::maps::COccupancyGridMap2D& grid, const std::string& frame, const ros::Time& stamp)
{
	nav_msgs::OccupancyGrid msg;
	msg.header.stamp = stamp;
	msg.header.frame_id = frame;
	msg.info.map_load_time = stamp;
	msg.info.resolution = grid.getResolution();
	msg.info.width = grid.getSizeX();
	msg.info.height = grid.getSizeY();
	msg.info.origin.position.x = grid.getXMin();
	msg.info.origin.position.y = grid.getYMin();
	msg.info.origin.orientation.w = 1.0;
	msg.data.resize(static_cast<size_t>(msg.info.width) * msg.info.height);
	gridToRos(grid, msg.data.data());
	return msg;
}

}  // namespace rbpf_slam
