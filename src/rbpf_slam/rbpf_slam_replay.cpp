// rbpf_slam_replay: rbpf_slam over a bag, every scan offered to the filter (none dropped, however
// long each takes), as gmapping's slam_gmapping_replay:
//   rbpf_slam_replay --bag_filename BAG [--scan_topic /scan] [--seed N] [--on_done CMD]
//                    [--snapshot_every SECONDS --snapshot_prefix PREFIX]
// Its private parameters are rbpf_slam's (gmapping's names). The bag's /tf and /tf_static give the
// odometry and the laser's pose. At the end it publishes the last map on `map` (latched) and
// `map_metadata`, runs CMD (e.g. a map saver) while it holds them, and exits; it prints
// `update frame N` for each scan processed and a last line of scans received and processed.
// With --snapshot_every T it also writes the map as it stood every T seconds of bag time (from the
// bag's first message), before the first scan at or past that time is offered, as map_server files
// PREFIX_tSSSSS.{pgm,yaml} (SSSSS: whole seconds): the maps a live run would have published along
// the way. Snapshots only read the filter's best grid, so the final map is the same with or without.
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
#include <fstream>
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
		"                        [--snapshot_every SECONDS --snapshot_prefix PREFIX]\n"
		"  (private ROS parameters as rbpf_slam's: base_frame, odom_frame, map_frame, particles, delta, ...)\n");
}

// The grid as map_server files (the project's mapio.save_map layout): PREFIX.pgm, row 0 at the top,
// occupied (>= 65) 0, free (0..19) 254, unknown 205; PREFIX.yaml with the resolution (m/cell) and the
// origin (m, the lower left cell's corner in the map frame). False when a file cannot be written.
bool writeMapFiles(const nav_msgs::OccupancyGrid& map, const std::string& prefix)
{
	const std::string pgmPath = prefix + ".pgm";
	std::ofstream pgm(pgmPath, std::ios::binary);
	const unsigned w = map.info.width, h = map.info.height;
	pgm << "P5\n" << w << " " << h << "\n255\n";
	std::vector<unsigned char> row(w);
	for (unsigned y = h; y-- > 0;)
	{
		for (unsigned x = 0; x < w; ++x)
		{
			const int v = map.data[static_cast<size_t>(y) * w + x];
			row[x] = v >= 65 ? 0 : (v >= 0 && v <= 19 ? 254 : 205);
		}
		pgm.write(reinterpret_cast<const char*>(row.data()), static_cast<std::streamsize>(w));
	}
	pgm.close();
	std::ofstream yml(prefix + ".yaml");
	const std::string base = pgmPath.substr(pgmPath.find_last_of('/') + 1);
	yml.precision(17);
	yml << "image: " << base << "\nresolution: " << map.info.resolution << "\norigin: ["
		<< map.info.origin.position.x << ", " << map.info.origin.position.y
		<< ", 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n";
	yml.close();
	return static_cast<bool>(pgm) && static_cast<bool>(yml);
}

}  // namespace

int main(int argc, char** argv)
{
	ros::init(argc, argv, "rbpf_slam");
	std::string bagFile, scanTopic = "/scan", onDone, snapshotPrefix;
	int seed = 0;
	double snapshotEvery = 0.0;  // s of bag time; 0: no snapshots
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
		else if (a == "--snapshot_every" && hasValue) snapshotEvery = std::atof(argv[++i]);
		else if (a == "--snapshot_prefix" && hasValue) snapshotPrefix = argv[++i];
		else
		{
			std::fprintf(stderr, "rbpf_slam_replay: unknown or incomplete argument '%s'\n", a.c_str());
			usage(stderr);
			return 2;
		}
	}
	if (snapshotEvery > 0.0 && snapshotPrefix.empty())
	{
		std::fprintf(stderr, "rbpf_slam_replay: --snapshot_every needs --snapshot_prefix\n");
		usage(stderr);
		return 2;
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
	std::uint64_t noOdom = 0, snapshots = 0;
	double nextSnapshot = snapshotEvery;  // s since the bag's first message
	for (const auto& m : rosbag::View(bag, rosbag::TopicQuery(scanTopic)))
	{
		const auto scan = m.instantiate<sensor_msgs::LaserScan>();
		if (!scan) continue;
		const double bagTime = (m.getTime() - whole.getBeginTime()).toSec();
		while (snapshotEvery > 0.0 && bagTime >= nextSnapshot)
		{
			if (const auto* grid = mapper.bestGrid())
			{
				char name[32];
				std::snprintf(name, sizeof name, "_t%05d", static_cast<int>(std::lround(nextSnapshot)));
				if (writeMapFiles(rbpf_slam::gridMessage(*grid, mapFrame, ros::Time(0)), snapshotPrefix + name))
					++snapshots;
				else
					std::fprintf(stderr, "rbpf_slam_replay: cannot write the snapshot %s%s\n", snapshotPrefix.c_str(), name);
			}
			nextSnapshot += snapshotEvery;
		}
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
	std::printf("rbpf_slam_replay: %s\n", mapper.gyroScale().summary().c_str());
	if (snapshotEvery > 0.0)
		std::printf("rbpf_slam_replay: %llu snapshots every %g s of bag time\n",
					static_cast<unsigned long long>(snapshots), snapshotEvery);
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
