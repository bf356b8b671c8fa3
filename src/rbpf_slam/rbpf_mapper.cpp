#include "rbpf_mapper.h"

#include <mrpt/maps/CLogOddsGridMapLUT.h>
#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPosePDFGaussian.h>
#include <mrpt/maps/CSimpleMap.h>
#include <mrpt/random/RandomGenerators.h>

#include <chrono>
#include <cmath>

namespace rbpf_slam
{
using mrpt::maps::COccupancyGridMap2D;
using mrpt::poses::CPose2D;

RbpfMapper::RbpfMapper(const Options& o) : options_(o)
{
	mrpt::slam::CMetricMapBuilderRBPF::TConstructionOptions c;
	// the filter runs on every scan offered to it: the update rule is ours (gmapping's)
	c.insertionLinDistance = 0;
	c.insertionAngDistance = 0;
	c.localizeLinDistance = 0;
	c.localizeAngDistance = 0;
	c.verbosity_level = mrpt::system::LVL_ERROR;

	c.PF_options.PF_algorithm = mrpt::bayes::CParticleFilter::pfOptimalProposal;
	c.PF_options.resamplingMethod = mrpt::bayes::CParticleFilter::prSystematic;
	c.PF_options.adaptiveSampleSize = false;
	c.PF_options.sampleSize = static_cast<unsigned int>(o.particles);
	c.PF_options.BETA = 0.5;  // resample when the effective sample size falls under half (gmapping's resampleThreshold)
	c.PF_options.powFactor = 1.0;

	// the proposal: each particle's scan matched against its own grid (ICP on the grid)
	c.predictionOptions.pfOptimalProposal_mapSelection = 0;
	c.predictionOptions.ICPGlobalAlign_MinQuality = static_cast<float>(o.matchMinGoodness);
	auto& icp = c.predictionOptions.icp_params;
	icp.ICP_algorithm = mrpt::slam::icpClassic;
	icp.maxIterations = 40;
	// each scan point looks for grid walls this far from it at first: the cost of a match grows
	// with its square, and a particle's guess (its last pose plus the odometry since) is within
	// a few centimetres of where the scan fits
	icp.thresholdDist = o.matchSearchRadius;
	icp.thresholdAng = 0.15 * M_PI / 180.0;
	icp.ALFA = 0.5;
	icp.smallestThresholdDist = std::max(o.delta, 0.05);
	icp.onlyUniqueRobust = false;
	icp.skip_cov_calculation = false;

	COccupancyGridMap2D::TMapDefinition grid;
	grid.min_x = static_cast<float>(o.xmin);
	grid.max_x = static_cast<float>(o.xmax);
	grid.min_y = static_cast<float>(o.ymin);
	grid.max_y = static_cast<float>(o.ymax);
	grid.resolution = static_cast<float>(o.delta);
	grid.insertionOpts.maxDistanceInsertion = static_cast<float>(o.maxUrange);
	grid.insertionOpts.maxOccupancyUpdateCertainty = 0.65f;
	grid.insertionOpts.considerInvalidRangesAsFreeSpace = true;
	grid.insertionOpts.wideningBeamsWithDistance = false;
	grid.likelihoodOpts.likelihoodMethod = COccupancyGridMap2D::lmLikelihoodField_Thrun;
	grid.likelihoodOpts.LF_decimation = 5;
	grid.likelihoodOpts.LF_stdHit = static_cast<float>(std::max(4.0 * o.sigma, o.delta));
	grid.likelihoodOpts.LF_maxCorrsDistance = 0.30f;
	grid.likelihoodOpts.LF_zHit = 0.999f;
	grid.likelihoodOpts.LF_zRandom = 0.001f;
	grid.likelihoodOpts.LF_maxRange = static_cast<float>(o.maxUrange);
	grid.likelihoodOpts.enableLikelihoodCache = true;
	c.mapsInitializers.push_back(grid);

	// the odometry's error model: only the mean seeds each particle's scan match
	motion_.modelSelection = mrpt::obs::CActionRobotMovement2D::mmGaussian;
	motion_.gaussianModel.a1 = o.srr;
	motion_.gaussianModel.a2 = o.srt;
	motion_.gaussianModel.a3 = o.str;
	motion_.gaussianModel.a4 = o.stt;

	const auto seed = o.seed != 0
		? static_cast<std::uint32_t>(o.seed)
		: static_cast<std::uint32_t>(std::chrono::steady_clock::now().time_since_epoch().count());
	mrpt::random::getRandomGenerator().randomize(seed);

	builder_ = std::make_unique<mrpt::slam::CMetricMapBuilderRBPF>(c);
	builder_->setVerbosityLevel(mrpt::system::LVL_ERROR);
	// its particles' scan matches warn on every poor match (odometry used instead): not news
	builder_->mapPDF.setVerbosityLevel(mrpt::system::LVL_ERROR);
	builder_->options.enableMapUpdating = true;
	builder_->options.debugForceInsertion = true;
	// initialised at the first processed scan, at its odometry pose (offer)
}

bool RbpfMapper::offer(double stamp, const CPose2D& odom, const mrpt::obs::CObservation2DRangeScan& scan)
{
	++received_;
	bool process = processed_ == 0;
	if (!process)
	{
		// gmapping's rule: distance and turn summed scan to scan since the last processed scan
		const CPose2D step = odom - prevOdom_;
		linearSum_ += std::hypot(step.x(), step.y());
		angularSum_ += std::abs(step.phi());
		process = linearSum_ >= options_.linearUpdate || angularSum_ >= options_.angularUpdate ||
			(options_.temporalUpdate >= 0 && stamp - lastStamp_ > options_.temporalUpdate);
	}
	prevOdom_ = odom;
	if (!process) return false;
	if (processed_ == 0)
	{
		// the map frame is the odometry frame at the first scan, as gmapping's: the robot starts
		// at its odometry pose (a node started after the robot moved still maps in its odom frame)
		const mrpt::poses::CPosePDFGaussian start(odom);
		builder_->initialize(mrpt::maps::CSimpleMap(), &start);
	}

	mrpt::obs::CActionCollection actions;
	mrpt::obs::CActionRobotMovement2D move;
	// the odometry since the last processed scan, in that scan's base frame (zero for the first)
	move.computeFromOdometry(processed_ == 0 ? CPose2D() : odom - lastOdom_, motion_);
	move.timestamp = scan.timestamp;
	actions.insert(move);
	mrpt::obs::CSensoryFrame frame;
	frame.insert(std::make_shared<mrpt::obs::CObservation2DRangeScan>(scan));
	builder_->processActionObservation(actions, frame);

	++processed_;
	linearSum_ = angularSum_ = 0;
	lastStamp_ = stamp;
	lastOdom_ = odom;
	return true;
}

CPose2D RbpfMapper::bestPose() const
{
	const auto& pdf = builder_->mapPDF;
	size_t best = 0;
	for (size_t i = 1; i < pdf.particlesCount(); ++i)
		if (pdf.getW(i) > pdf.getW(best)) best = i;
	bool valid = false;
	const auto p = pdf.getLastPose(best, valid);
	return CPose2D(p.x, p.y, p.yaw);
}

const COccupancyGridMap2D* RbpfMapper::bestGrid() const
{
	if (processed_ == 0) return nullptr;
	const auto* maps = builder_->getCurrentlyBuiltMetricMap();
	if (!maps) return nullptr;
	const auto grid = maps->mapByClass<COccupancyGridMap2D>();
	return grid ? grid.get() : nullptr;
}

void gridToRos(const COccupancyGridMap2D& grid, std::int8_t* out)
{
	const unsigned w = grid.getSizeX(), h = grid.getSizeY();
	for (unsigned y = 0; y < h; ++y)
	{
		const COccupancyGridMap2D::cellType* row = grid.getRow(y);
		for (unsigned x = 0; x < w; ++x)
		{
			// a cell's log-odds of being free: 0 before any evidence
			const auto v = row[x];
			*out++ = v == 0 ? -1 : (v < 0 ? 100 : 0);
		}
	}
}

}  // namespace rbpf_slam
