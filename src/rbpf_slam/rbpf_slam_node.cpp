// rbpf_slam: one robot's live grid SLAM over MRPT's Rao-Blackwellized particle filter, with
// slam_gmapping's interface: it subscribes `scan` and reads the odometry from TF
// (odom_frame -> base_frame at each scan's stamp), and publishes `map` and `map_metadata`
// (latched), the TF map_frame -> odom_frame, and the service `dynamic_map`. Its private
// parameters take gmapping's names where they mean the same; a gmapping YAML loads as it is
// (what has no counterpart here is ignored). Prints `update frame N` for each scan it processes
// (N counts every scan that reached the update rule), as gmapping does.
#include "rbpf_ros.h"

#include <message_filters/subscriber.h>
#include <nav_msgs/GetMap.h>
#include <nav_msgs/MapMetaData.h>
#include <nav_msgs/OccupancyGrid.h>
#include <ros/ros.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/message_filter.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

namespace
{
using mrpt::poses::CPose2D;

class RbpfSlamNode
{
   public:
	RbpfSlamNode() : pnh_("~"), tfListener_(tfBuffer_)
	{
		const rbpf_slam::NodeSettings settings = rbpf_slam::readSettings(pnh_);
		const rbpf_slam::Options& o = settings.filter;
		baseFrame_ = settings.baseFrame;
		odomFrame_ = settings.odomFrame;
		mapFrame_ = settings.mapFrame;
		maxRange_ = o.maxRange;
		mapUpdateInterval_ = settings.mapUpdateInterval;
		transformPeriod_ = settings.transformPublishPeriod;
		mapper_ = std::make_unique<rbpf_slam::RbpfMapper>(o);

		mapPub_ = nh_.advertise<nav_msgs::OccupancyGrid>("map", 1, true);
		metaPub_ = nh_.advertise<nav_msgs::MapMetaData>("map_metadata", 1, true);
		mapService_ = nh_.advertiseService("dynamic_map", &RbpfSlamNode::mapCallback, this);
		scanSub_ = std::make_unique<message_filters::Subscriber<sensor_msgs::LaserScan>>(nh_, "scan", 5);
		scanFilter_ = std::make_unique<tf2_ros::MessageFilter<sensor_msgs::LaserScan>>(
			*scanSub_, tfBuffer_, odomFrame_, 5, nh_);
		scanFilter_->registerCallback(&RbpfSlamNode::scanCallback, this);
		ROS_INFO(
			"rbpf_slam: %d particles, %.3f m cells, maxUrange %.1f m, update every %.2f m / %.2f rad / %.1f s; "
			"frames %s -> %s -> %s",
			o.particles, o.delta, o.maxUrange, o.linearUpdate, o.angularUpdate, o.temporalUpdate, mapFrame_.c_str(),
			odomFrame_.c_str(), baseFrame_.c_str());
		if (transformPeriod_ > 0) tfThread_ = std::thread([this] { publishTransformLoop(); });
	}

	~RbpfSlamNode()
	{
		stopping_ = true;
		if (tfThread_.joinable()) tfThread_.join();
		std::printf(
			"rbpf_slam: %llu scans received, %llu processed; particle moves: %llu by scan match, %llu by "
			"odometry\n",
			static_cast<unsigned long long>(mapper_->received()),
			static_cast<unsigned long long>(mapper_->processed()),
			static_cast<unsigned long long>(mapper_->matchedMoves()),
			static_cast<unsigned long long>(mapper_->odometryMoves()));
		std::printf("rbpf_slam: %s\n", mapper_->gyroScale().summary().c_str());
		std::fflush(stdout);
	}

   private:
	void scanCallback(const sensor_msgs::LaserScan::ConstPtr& scan)
	{
		const auto laser = laserPose(*scan);
		if (!laser) return;
		CPose2D odom;
		try
		{
			odom = rbpf_slam::pose2D(tfBuffer_.lookupTransform(odomFrame_, baseFrame_, scan->header.stamp).transform);
		}
		catch (const tf2::TransformException& e)
		{
			ROS_WARN_THROTTLE(5.0, "rbpf_slam: no odometry pose for a scan (%s): scan dropped", e.what());
			return;
		}
		mrpt::obs::CObservation2DRangeScan obs;
		if (!rbpf_slam::toObservation(*scan, *laser, maxRange_, obs))
		{
			ROS_WARN_THROTTLE(5.0, "rbpf_slam: a scan could not be converted: dropped");
			return;
		}
		const std::uint64_t frame = mapper_->received();
		const std::uint64_t scaleUpdates = mapper_->gyroScale().updates();
		if (!mapper_->offer(scan->header.stamp.toSec(), odom, obs)) return;
		std::printf("update frame %llu\n", static_cast<unsigned long long>(frame));
		std::fflush(stdout);
		if (mapper_->gyroScale().updates() != scaleUpdates)
			ROS_INFO("rbpf_slam: %s", mapper_->gyroScale().summary().c_str());

		// map -> odom: the base's pose in the map, composed with its inverse odometry pose
		const CPose2D mapToOdom = mapper_->bestPose() + (CPose2D() - mapper_->lastProcessedOdom());
		{
			std::lock_guard<std::mutex> lock(tfMutex_);
			mapToOdom_ = mapToOdom;
		}
		if (!gotMap_ || (scan->header.stamp - lastMapUpdate_).toSec() > mapUpdateInterval_)
		{
			publishMap();
			lastMapUpdate_ = scan->header.stamp;
		}
	}

	/** The laser's pose on the base (its frame looked up once per frame id); none while TF has none. */
	const mrpt::poses::CPose3D* laserPose(const sensor_msgs::LaserScan& scan)
	{
		auto it = laserPoses_.find(scan.header.frame_id);
		if (it != laserPoses_.end()) return &it->second;
		geometry_msgs::TransformStamped t;
		try
		{
			t = tfBuffer_.lookupTransform(baseFrame_, scan.header.frame_id, scan.header.stamp);
		}
		catch (const tf2::TransformException& e)
		{
			ROS_WARN_THROTTLE(
				5.0, "rbpf_slam: no TF from %s to the laser's frame %s (%s): scan dropped", baseFrame_.c_str(),
				scan.header.frame_id.c_str(), e.what());
			return nullptr;
		}
		const mrpt::poses::CPose3D pose = rbpf_slam::pose3D(t.transform);
		ROS_INFO(
			"rbpf_slam: laser %s at (%.3f, %.3f) m, %.1f deg on %s", scan.header.frame_id.c_str(), pose.x(),
			pose.y(), pose.yaw() * 180 / M_PI, baseFrame_.c_str());
		return &laserPoses_.emplace(scan.header.frame_id, pose).first->second;
	}

	void publishMap()
	{
		const auto* grid = mapper_->bestGrid();
		if (!grid) return;
		const nav_msgs::OccupancyGrid msg = rbpf_slam::gridMessage(*grid, mapFrame_, ros::Time::now());
		{
			std::lock_guard<std::mutex> lock(mapMutex_);
			map_ = msg;
			gotMap_ = true;
		}
		mapPub_.publish(msg);
		metaPub_.publish(msg.info);
	}

	bool mapCallback(nav_msgs::GetMap::Request&, nav_msgs::GetMap::Response& res)
	{
		std::lock_guard<std::mutex> lock(mapMutex_);
		if (!gotMap_) return false;
		res.map = map_;
		return true;
	}

	void publishTransformLoop()
	{
		ros::WallRate rate(1.0 / transformPeriod_);
		while (!stopping_ && ros::ok())
		{
			geometry_msgs::TransformStamped t;
			{
				std::lock_guard<std::mutex> lock(tfMutex_);
				t.transform.translation.x = mapToOdom_.x();
				t.transform.translation.y = mapToOdom_.y();
				tf2::Quaternion q;
				q.setRPY(0, 0, mapToOdom_.phi());
				t.transform.rotation.x = q.x();
				t.transform.rotation.y = q.y();
				t.transform.rotation.z = q.z();
				t.transform.rotation.w = q.w();
			}
			// stamped ahead by one period, as slam_gmapping does, so lookups at "now" find it;
			// under simulated time the clock may not have moved since the last one: sent once
			t.header.stamp = ros::Time::now() + ros::Duration(transformPeriod_);
			if (t.header.stamp == lastTfStamp_)
			{
				rate.sleep();
				continue;
			}
			lastTfStamp_ = t.header.stamp;
			t.header.frame_id = mapFrame_;
			t.child_frame_id = odomFrame_;
			broadcaster_.sendTransform(t);
			rate.sleep();
		}
	}

	ros::NodeHandle nh_, pnh_;
	tf2_ros::Buffer tfBuffer_;
	tf2_ros::TransformListener tfListener_;
	tf2_ros::TransformBroadcaster broadcaster_;
	std::string baseFrame_, odomFrame_, mapFrame_;
	double maxRange_ = 8, mapUpdateInterval_ = 5, transformPeriod_ = 0.05;
	std::unique_ptr<rbpf_slam::RbpfMapper> mapper_;
	ros::Publisher mapPub_, metaPub_;
	ros::ServiceServer mapService_;
	std::unique_ptr<message_filters::Subscriber<sensor_msgs::LaserScan>> scanSub_;
	std::unique_ptr<tf2_ros::MessageFilter<sensor_msgs::LaserScan>> scanFilter_;
	std::map<std::string, mrpt::poses::CPose3D> laserPoses_;
	std::mutex tfMutex_, mapMutex_;
	CPose2D mapToOdom_;
	nav_msgs::OccupancyGrid map_;
	bool gotMap_ = false;
	ros::Time lastMapUpdate_, lastTfStamp_;
	std::thread tfThread_;
	std::atomic<bool> stopping_{false};
};
}  // namespace

int main(int argc, char** argv)
{
	for (int i = 1; i < argc; ++i)
		if (std::string(argv[i]) == "-h" || std::string(argv[i]) == "--help")
		{
			std::printf(
				"usage: rbpf_slam [__name:=NAME] [scan:=TOPIC ...]\n"
				"  one robot's live grid SLAM (MRPT's Rao-Blackwellized particle filter) with slam_gmapping's\n"
				"  interface: subscribes scan and the odometry TF; publishes map, map_metadata, the TF\n"
				"  map_frame -> odom_frame and the service dynamic_map. Private parameters (gmapping's names):\n"
				"  base_frame odom_frame map_frame particles delta xmin ymin xmax ymax maxRange maxUrange\n"
				"  linearUpdate angularUpdate temporalUpdate map_update_interval transform_publish_period\n"
				"  srr srt str stt min_std_xy min_std_yaw sigma match_min_goodness match_search_radius seed\n"
				"  gyro_scale_learning gyro_scale_limit gyro_scale_window gyro_scale_prior_sigma (docs/rbpf_slam.md)\n");
			return 0;
		}
	ros::init(argc, argv, "rbpf_slam");
	RbpfSlamNode node;
	ros::spin();
	return 0;
}
