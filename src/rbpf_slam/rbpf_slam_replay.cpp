// rbpf_slam_replay: rbpf_slam over a bag, every scan offered to the filter (none dropped, however
// long each takes), as gmapping's slam_gmapping_replay:
//   rbpf_slam_replay --bag_filename BAG [--scan_topic /scan] [--seed N] [--on_done CMD]
// Its private parameters are rbpf_slam's (gmapping's names). The bag's /tf and /tf_static give the
// odometry and the laser's pose. At the end it publishes the last map on `map` (latched) and
// `map_metadata`, runs CMD (e.g. a map saver) while it holds them, and exits; it prints
// `update frame N` for each scan processed and a last line of scans received and processed.
#include "rbpf_ros.h"

#include <nav_msgs/MapMetaData.h>
#include <nav_msgs/OccupancyGrid.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2/buffer_core.h>
#include <tf2/exceptions.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

namespace
{
void usage(std::FILE* to)
{
	std::fprintf(
		to,
		"usage: rbpf_slam_replay --bag_filename BAG [--scan_topic /scan] [--seed N] [--on_done CMD]\n"
		"  (private ROS parameters as rbpf_slam's: base_frame, odom_frame, map_frame, particles, delta, ...)\n");
}

}  // namespace

int main(int argc, char** argv)
{
	ros::init(argc, argv, "rbpf_slam");
	std::string bagFile, scanTopic = "/scan", onDone;
	int seed = 0;
	for (int i = 1; i < argc; ++i)
	{
		const std::string a = argv[i];
		const bool hasValue = i + 1 < argc;
		if (a == "-h" || a == "--help")
		{
			usage(stdout);
			return 0;
		}
		if (a == "--bag_filename" && hasValue) bagFile = argv[++i];
		else if (a == "--scan_topic" && hasValue) scanTopic = argv[++i];
		else if (a == "--seed" && hasValue) seed = std::atoi(argv[++i]);
		else if (a == "--on_done" && hasValue) onDone = argv[++i];
		else
		{
			std::fprintf(stderr, "rbpf_slam_replay: unknown or incomplete argument '%s'\n", a.c_str());
			usage(stderr);
			return 2;
		}
	}
	if (bagFile.empty())
	{
		usage(stderr);
		return 2;
	}

	ros::NodeHandle nh, pnh("~");
	const rbpf_slam::NodeSettings settings = rbpf_slam::readSettings(pnh);
	const std::string &baseFrame = settings.baseFrame, &odomFrame = settings.odomFrame, &mapFrame = settings.mapFrame;
	rbpf_slam::Options o = settings.filter;
	if (seed != 0) o.seed = seed;

	rosbag::Bag bag;
	try
	{
		bag.open(bagFile, rosbag::bagmode::Read);
	}
	catch (const rosbag::BagException& e)
	{
		std::fprintf(stderr, "rbpf_slam_replay: cannot read %s: %s\n", bagFile.c_str(), e.what());
		return 2;
	}
	// every transform of the bag first: a scan's odometry may be recorded just after it
	rosbag::View whole(bag);
	const ros::Duration span = whole.getEndTime() - whole.getBeginTime();
	tf2::BufferCore tf(span + ros::Duration(60.0));
	for (const auto& m : rosbag::View(bag, rosbag::TopicQuery(std::vector<std::string>{"/tf", "/tf_static"})))
	{
		const auto msg = m.instantiate<tf2_msgs::TFMessage>();
		if (!msg) continue;
		const bool isStatic = m.getTopic() == "/tf_static";
		for (const auto& t : msg->transforms) tf.setTransform(t, "bag", isStatic);
	}

	rbpf_slam::RbpfMapper mapper(o);
	std::unique_ptr<mrpt::poses::CPose3D> laser;
	std::uint64_t noOdom = 0;
	for (const auto& m : rosbag::View(bag, rosbag::TopicQuery(scanTopic)))
	{
		const auto scan = m.instantiate<sensor_msgs::LaserScan>();
		if (!scan) continue;
		try
		{
			if (!laser)
			{
				laser = std::make_unique<mrpt::poses::CPose3D>(rbpf_slam::pose3D(
					tf.lookupTransform(baseFrame, scan->header.frame_id, scan->header.stamp).transform));
			}
			const mrpt::poses::CPose2D odom =
				rbpf_slam::pose2D(tf.lookupTransform(odomFrame, baseFrame, scan->header.stamp).transform);
			mrpt::obs::CObservation2DRangeScan obs;
			if (!rbpf_slam::toObservation(*scan, *laser, o.maxRange, obs)) continue;
			const std::uint64_t frame = mapper.received();
			if (mapper.offer(scan->header.stamp.toSec(), odom, obs))
			{
				std::printf("update frame %llu\n", static_cast<unsigned long long>(frame));
				std::fflush(stdout);
			}
		}
		catch (const tf2::TransformException& e)
		{
			if (noOdom++ == 0)
				std::fprintf(stderr, "rbpf_slam_replay: a scan without its TF (%s): skipped\n", e.what());
		}
	}
	bag.close();
	std::printf(
		"rbpf_slam_replay: %llu scans received, %llu processed, %llu without TF; particle moves: %llu by "
		"scan match, %llu by odometry\n",
		static_cast<unsigned long long>(mapper.received()), static_cast<unsigned long long>(mapper.processed()),
		static_cast<unsigned long long>(noOdom), static_cast<unsigned long long>(mapper.matchedMoves()),
		static_cast<unsigned long long>(mapper.odometryMoves()));
	std::fflush(stdout);

	const auto* grid = mapper.bestGrid();
	if (!grid)
	{
		std::fprintf(stderr, "rbpf_slam_replay: no scan processed: no map\n");
		return 1;
	}
	const nav_msgs::OccupancyGrid map = rbpf_slam::gridMessage(*grid, mapFrame, ros::Time::now());
	ros::Publisher mapPub = nh.advertise<nav_msgs::OccupancyGrid>("map", 1, true);
	ros::Publisher metaPub = nh.advertise<nav_msgs::MapMetaData>("map_metadata", 1, true);
	mapPub.publish(map);
	metaPub.publish(map.info);
	int rc = 0;
	if (!onDone.empty())
	{
		ros::AsyncSpinner spinner(1);
		spinner.start();
		rc = std::system(onDone.c_str());
		if (rc != 0) std::fprintf(stderr, "rbpf_slam_replay: --on_done exited %d\n", rc);
	}
	return rc == 0 ? 0 : 1;
}
