#include "rbpf_mapper.h"

#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/random/RandomGenerators.h>
#include <mrpt/slam/CICP.h>
#include <mrpt/maps/CSimplePointsMap.h>
#include <mrpt/poses/CPoseRandomSampler.h>
#include <mrpt/math/wrap2pi.h>
#include <mrpt/maps/CMultiMetricMapPDF.h>

#include <Eigen/Dense>

#include <chrono>
#include <cmath>

namespace rbpf_slam
{
using mrpt::maps::COccupancyGridMap2D;
using mrpt::poses::CPose2D;

/** The particles, with the proposal of Grisetti, Stachniss and Burgard (2007): each particle's
 * scan is matched against its own grid from its odometry guess (ICP on the grid), and its new pose
 * drawn from the match's Gaussian times the odometry's (the scan's evidence times the motion
 * model). A match that is poor (a low share of the scan's points paired) or that lands where the
 * odometry could not have taken the robot is not trusted: the odometry's own distribution places
 * that particle. Its weight is the scan's likelihood in its grid at the pose drawn.
 *
 * Written here rather than MRPT's CMultiMetricMapPDF::prediction_and_update_pfOptimalProposal
 * used: in MRPT 2.5.8 that one draws around the match alone, and around a poor match too (its
 * odometry fallback is set after the pose to draw from was copied). */
class ScanMatchParticles : public mrpt::maps::CMultiMetricMapPDF
{
   public:
	ScanMatchParticles(
		const mrpt::bayes::CParticleFilter::TParticleFilterOptions& pf,
		const mrpt::maps::TSetOfMetricMapInitializers& maps, const TPredictionParams& prediction,
		double gate)
		: CMultiMetricMapPDF(pf, maps, prediction), gate_(gate)
	{
	}

	std::uint64_t matched = 0, odometry = 0;  //!< particle moves by scan match, by odometry
	// the last step's scan-match turns (rad, match heading minus the particle's last heading),
	// summed over the particles whose match was trusted, and their number
	double stepMatchTurnSum = 0;
	std::size_t stepMatchTurns = 0;

   protected:
	void prediction_and_update_pfOptimalProposal(
		const mrpt::obs::CActionCollection* actions, const mrpt::obs::CSensoryFrame* sf,
		const mrpt::bayes::CParticleFilter::TParticleFilterOptions& pfOptions) override
	{
		using mrpt::poses::CPose3D;
		const auto move = actions->getBestMovementEstimation();
		ASSERT_(move && sf);
		const auto [odomCov, odomMean] = move->poseChange->getCovarianceAndMean();
		mrpt::poses::CPoseRandomSampler odomSampler;
		odomSampler.setPosePDF(*move->poseChange);

		mrpt::maps::CSimplePointsMap scanPoints;
		scanPoints.insertionOptions.minDistBetweenLaserPoints = 0.02f;
		scanPoints.insertionOptions.isPlanarMap = true;
		sf->insertObservationsInto(scanPoints);

		mrpt::slam::CICP icp(options.icp_params);
		const Eigen::Matrix3d odomLocal = odomCov.asEigen();
		// the least spread of a scan match: its own estimate is too sure of itself where the
		// walls it matched are a few cells thick
		constexpr double floorXY = 0.01, floorYaw = 0.5 * M_PI / 180.0;

		// the first scan finds every grid empty: the particles stay at the start pose, which
		// defines the map frame, and it only goes into their grids
		const bool firstScan = getNumberOfObservationsInSimplemap() == 0;

		mrpt::math::CVectorDouble noise;
		stepMatchTurnSum = 0;
		stepMatchTurns = 0;
		for (size_t i = 0; i < m_particles.size(); ++i)
		{
			auto& particle = *m_particles[i].d;
			if (firstScan)
			{
				particle.robotPath.push_back(particle.robotPath.back());
				continue;
			}
			const CPose2D last(CPose3D(particle.robotPath.back()));
			const CPose2D guess = last + odomMean;
			// the odometry's spread of the guess, turned from the last pose's frame into the map's
			Eigen::Matrix3d rot = Eigen::Matrix3d::Identity();
			rot.topLeftCorner<2, 2>() = Eigen::Rotation2Dd(last.phi()).toRotationMatrix();
			const Eigen::Matrix3d guessCov = rot * odomLocal * rot.transpose();
			const auto grid = particle.mapTillNow.mapByClass<COccupancyGridMap2D>();
			ASSERT_(grid);
			mrpt::slam::CICP::TReturnInfo info;
			const auto match = icp.Align(grid.get(), &scanPoints, guess, info);
			const auto [matchCovM, matchMean] = match->getCovarianceAndMean();
			Eigen::Matrix3d matchCov = matchCovM.asEigen();
			matchCov(0, 0) = std::max(matchCov(0, 0), floorXY * floorXY);
			matchCov(1, 1) = std::max(matchCov(1, 1), floorXY * floorXY);
			matchCov(2, 2) = std::max(matchCov(2, 2), floorYaw * floorYaw);

			// a match is believed where it is within the gate of the odometry's guess, in the
			// odometry's spread and the match's together
			const Eigen::Vector3d d(matchMean.x() - guess.x(), matchMean.y() - guess.y(),
				mrpt::math::wrapToPi(matchMean.phi() - guess.phi()));
			const Eigen::Matrix3d both = guessCov + matchCov;
			const double d2 = d.dot(both.ldlt().solve(d));
			CPose2D drawn;
			if (info.goodness >= options.ICPGlobalAlign_MinQuality && d2 <= gate_)
			{
				// the proposal: the scan's evidence (the match, a Gaussian) times the motion
				// model (the odometry's guess, a Gaussian), as Grisetti et al. 2007 draw from
				const Eigen::Matrix3d gain = guessCov * both.inverse();
				const Eigen::Matrix3d cov = guessCov - gain * guessCov;
				const Eigen::Vector3d mean = Eigen::Vector3d(guess.x(), guess.y(), guess.phi()) + gain * d;
				mrpt::math::CMatrixDouble33 c(cov);
				mrpt::random::getRandomGenerator().drawGaussianMultivariate(noise, c);
				drawn = CPose2D(mean[0] + noise[0], mean[1] + noise[1], mrpt::math::wrapToPi(mean[2] + noise[2]));
				++matched;
				stepMatchTurnSum += mrpt::math::wrapToPi(matchMean.phi() - last.phi());
				++stepMatchTurns;
			}
			else
			{
				CPose2D step;
				odomSampler.drawSample(step);
				drawn = last + step;
				++odometry;
			}
			particle.robotPath.push_back(CPose3D(drawn).asTPose());
			m_particles[i].log_w += pfOptions.powFactor *
				PF_SLAM_computeObservationLikelihoodForParticle(pfOptions, i, *sf, CPose3D(drawn));
		}
	}

   private:
	double gate_;  //!< squared Mahalanobis distance (3 dof) of a match to the odometry's guess
};

RbpfMapper::~RbpfMapper() = default;

RbpfMapper::RbpfMapper(const Options& o) : options_(o), gyroScale_(o.gyroScale)
{
	// the filter runs on every scan offered to it: the update rule is ours (gmapping's)
	auto& pf = filter_.m_options;
	pf.PF_algorithm = mrpt::bayes::CParticleFilter::pfOptimalProposal;
	pf.resamplingMethod = mrpt::bayes::CParticleFilter::prSystematic;
	pf.adaptiveSampleSize = false;
	pf.sampleSize = static_cast<unsigned int>(o.particles);
	pf.BETA = 0.5;  // resample when the effective sample size falls under half (gmapping's resampleThreshold)
	pf.powFactor = 1.0;
	filter_.setVerbosityLevel(mrpt::system::LVL_ERROR);

	// the proposal: each particle's scan matched against its own grid (ICP on the grid)
	mrpt::maps::CMultiMetricMapPDF::TPredictionParams prediction;
	prediction.ICPGlobalAlign_MinQuality = static_cast<float>(o.matchMinGoodness);
	auto& icp = prediction.icp_params;
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
	// the cache is a double per cell of the whole grid, per particle, made again after every
	// insertion: each particle weighs a scan once between insertions, so it never pays back
	grid.likelihoodOpts.enableLikelihoodCache = false;
	mrpt::maps::TSetOfMetricMapInitializers maps;
	maps.push_back(grid);

	// the odometry's error model: its mean seeds each particle's scan match, its spread is the
	// motion model the match is weighed against
	motion_.modelSelection = mrpt::obs::CActionRobotMovement2D::mmGaussian;
	motion_.gaussianModel.a1 = o.srr;
	motion_.gaussianModel.a2 = o.srt;
	motion_.gaussianModel.a3 = o.str;
	motion_.gaussianModel.a4 = o.stt;
	motion_.gaussianModel.minStdXY = o.minStdXY;
	motion_.gaussianModel.minStdPHI = o.minStdYaw;

	const auto seed = o.seed != 0
		? static_cast<std::uint32_t>(o.seed)
		: static_cast<std::uint32_t>(std::chrono::steady_clock::now().time_since_epoch().count());
	mrpt::random::getRandomGenerator().randomize(seed);

	// a scan match further from the odometry's guess than 99 % of the two spreads together allow
	// (chi-square, 3 degrees of freedom) is not where the robot went
	particles_ = std::make_unique<ScanMatchParticles>(pf, maps, prediction, 11.34);
	particles_->setVerbosityLevel(mrpt::system::LVL_ERROR);
	// initialised at the first processed scan, at its odometry pose (offer)
}

/** The scan as MRPT's grid insertion reads it. MRPT spreads a scan's N beams over its aperture
 * in N - 1 steps when it matches or weighs a scan (points, likelihood), and in N steps when it
 * inserts one into a grid: the same observation would be drawn into the map squeezed by one
 * beam in N, a degree at the last beam of a 360-beam scan, and the map would bend. Here the
 * aperture is N steps and the sensor turned by half a step, so every beam lands at its own
 * angle in the grid too. */
static mrpt::obs::CSensoryFrame gridFrame(const mrpt::obs::CObservation2DRangeScan& scan)
{
	auto insert = std::make_shared<mrpt::obs::CObservation2DRangeScan>(scan);
	const double n = static_cast<double>(scan.getScanSize());
	const double step = scan.aperture / (n - 1.0);
	insert->aperture = static_cast<float>(step * n);
	insert->sensorPose = scan.sensorPose + mrpt::poses::CPose3D(0, 0, 0, (scan.rightToLeft ? 0.5 : -0.5) * step, 0, 0);
	mrpt::obs::CSensoryFrame frame;
	frame.insert(insert);
	return frame;
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
		particles_->clear(odom);
	}

	mrpt::obs::CActionCollection actions;
	mrpt::obs::CActionRobotMovement2D move;
	// the odometry since the last processed scan, in that scan's base frame (zero for the first),
	// its turn times the heading's scale factor learned so far (1 unless ~gyro_scale_learning)
	const CPose2D step = processed_ == 0 ? CPose2D() : odom - lastOdom_;
	move.computeFromOdometry(CPose2D(step.x(), step.y(), step.phi() * gyroScale_.scale()), motion_);
	move.timestamp = scan.timestamp;
	actions.insert(move);
	// the scan is matched and weighed by its beams within maxUrange, as gmapping's matcher uses
	// them: further readings are not in the particles' grids, which only take maxUrange of a beam
	auto matched = std::make_shared<mrpt::obs::CObservation2DRangeScan>(scan);
	for (size_t i = 0; i < matched->getScanSize(); ++i)
		if (matched->getScanRange(i) > options_.maxUrange) matched->setScanRangeValidity(i, false);
	mrpt::obs::CSensoryFrame frame;
	frame.insert(matched);
	// one step of the filter (the proposal and weights above, then resampling when the effective
	// sample size is low), and the scan inserted into every particle's grid at its new pose
	filter_.executeOn(*particles_, &actions, &frame);
	auto inserted = gridFrame(scan);
	particles_->insertObservation(inserted);
	for (auto& particle : particles_->m_particles) particle.d->mapTillNow.auxParticleFilterCleanUp();
	// the step's turn by the scan matches (their mean over the particles whose match was
	// trusted) against the odometry's own: a step where most particles fell back to the
	// odometry says nothing about its scale
	if (processed_ > 0 && 2 * particles_->stepMatchTurns >= particles_->m_particles.size())
		gyroScale_.addStep(step.phi(), particles_->stepMatchTurnSum / static_cast<double>(particles_->stepMatchTurns));

	++processed_;
	linearSum_ = angularSum_ = 0;
	lastStamp_ = stamp;
	lastOdom_ = odom;
	return true;
}

std::uint64_t RbpfMapper::matchedMoves() const { return particles_->matched; }
std::uint64_t RbpfMapper::odometryMoves() const { return particles_->odometry; }

CPose2D RbpfMapper::bestPose() const
{
	const auto& pdf = *particles_;
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
	const auto* maps = particles_->getCurrentMostLikelyMetricMap();
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
