// mrpt_grid_align: the project's driver of MRPT's occupancy grid aligner
// (mrpt::slam::CGridMapAligner, Blanco et al., Robotica 2013), used by the benchmarks only, as a
// reference merger measured beside ours (bench/mrpt_merge.py is its front end). Nothing of it is
// part of multi_map_merge.
//
//   mrpt_grid_align [--seed N] [--no-icp] RES GRID_0.png GRID_1.png ...
//
// Every GRID is a trinary image (255 free, 0 occupied, other values unknown) at RES metres a cell
// whose lower-left corner is the origin of the grid's frame (x right, y up). For every pair i < j
// it prints one JSON line:
//   {"i", "j", "kept", "modes", "pose": [x, y, yaw] (grid j's frame in grid i's frame, the most
//    likely mode of the returned sum of Gaussians), "cov": 9 numbers (that mode's), "icp_goodness",
//    "seconds"}
// and a last line {"peak_rss_kb"}: its own peak RSS (VmHWM).
// "kept" is MRPT's own verdict: the sum of Gaussians is not empty (some hypothesis passed the
// aligner's gates: RANSAC consensus, ICP goodness, ICP shift).
//
// Settings: those of MRPT's grid-matching example configuration (gridmatch_example.ini, [grid-match];
// Debian ships it in no binary package, so they are set here), then ransac_SOG_sigma_m = 2 x RES as
// MRPT's grid-matching application sets it; grid feature filters 3 x 3 (the example's grid section).
// Each map carries, beside its grid, a point map of its occupied cells that border other cells,
// standing in for the laser points grid-matching adds, so that the aligner's ICP stage runs.
#include <mrpt/maps/CMultiMetricMap.h>
#include <mrpt/maps/COccupancyGridMap2D.h>
#include <mrpt/maps/CSimplePointsMap.h>
#include <mrpt/poses/CPosePDFSOG.h>
#include <mrpt/random.h>
#include <mrpt/slam/CGridMapAligner.h>
#include <mrpt/slam/CICP.h>
#include <mrpt/system/COutputLogger.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

namespace
{
using mrpt::maps::CMultiMetricMap;
using mrpt::maps::COccupancyGridMap2D;
using mrpt::maps::CSimplePointsMap;
using mrpt::poses::CPose2D;
using mrpt::slam::CGridMapAligner;

void example_settings(CGridMapAligner::TConfigParams& o, float res)
{
	o.methodSelection = CGridMapAligner::amModifiedRANSAC;
	o.featsPerSquareMeter = 0.012f;
	o.threshold_max = 0.20f;
	o.threshold_delta = 0.09f;
	o.ransac_prob_good_inliers = 0.9999999999;
	o.maxKLd_for_merge = 0.9;
	o.min_ICP_goodness = 0.30f;
	o.max_ICP_mahadist = 10.0;
	o.ransac_minSetSizeRatio = 0.15f;
	o.ransac_mahalanobisDistanceThreshold = 6.0f;
	o.ransac_chi2_quantile = 0.5;
	o.save_feat_coors = false;
	o.debug_show_corrs = false;
	o.debug_save_map_pairs = false;	 // (the example writes debug images: not wanted here)
	auto& f = o.feature_detector_options;
	f.featsType = mrpt::vision::featHarris;
	f.patchSize = 0;
	f.KLTOptions.min_distance = 6;
	f.KLTOptions.threshold = 0.20f;
	f.harrisOptions.min_distance = 6;
	f.harrisOptions.threshold = 0.20f;
	o.feature_descriptor = mrpt::vision::descPolarImages;
	f.PolarImagesOptions.bins_angle = 8;
	f.PolarImagesOptions.bins_distance = 6;
	f.PolarImagesOptions.radius = 20;
	o.ransac_SOG_sigma_m = 2 * res;	 // as the grid-matching application does
}

// ICP goodness (fraction of points paired) of grid j's points placed at `pose` on grid i's,
// with the ICP settings CGridMapAligner uses for its own gate.
double icp_goodness(const CMultiMetricMap& a, const CMultiMetricMap& b, const CPose2D& pose)
{
	mrpt::slam::CICP icp;
	icp.options.maxIterations = 20;
	icp.options.thresholdDist = 0.75f;
	icp.options.smallestThresholdDist = 0.05f;
	mrpt::slam::CICP::TReturnInfo info;
	icp.Align(
		a.mapByClass<CSimplePointsMap>().get(), b.mapByClass<CSimplePointsMap>().get(), pose, info);
	return info.goodness;
}

}  // namespace

int main(int argc, char** argv)
{
	unsigned seed = 1;
	bool use_icp = true;
	std::vector<std::string> args;
	for (int k = 1; k < argc; k++)
	{
		const std::string a = argv[k];
		if (a == "--seed" && k + 1 < argc) seed = std::strtoul(argv[++k], nullptr, 10);
		else if (a == "--no-icp") use_icp = false;
		else args.push_back(a);
	}
	if (args.size() < 3)
	{
		std::cerr << "usage: mrpt_grid_align [--seed N] [--no-icp] RES GRID_0.png GRID_1.png ...\n";
		return 2;
	}
	try
	{
		const float res = std::stof(args[0]);
		std::vector<CMultiMetricMap> maps(args.size() - 1);
		for (size_t k = 0; k < maps.size(); k++)
		{
			auto grid = COccupancyGridMap2D::Create();
			grid->insertionOptions.CFD_features_gaussian_size = 3;
			grid->insertionOptions.CFD_features_median_size = 3;
			if (!grid->loadFromBitmapFile(args[k + 1], res, mrpt::math::TPoint2D(0, 0)))
			{
				std::cerr << "mrpt_grid_align: cannot read " << args[k + 1] << "\n";
				return 3;
			}
			maps[k].maps.push_back(grid);
			if (use_icp)
			{
				auto points = CSimplePointsMap::Create();
				grid->getAsPointCloud(*points, 0.25f);
				maps[k].maps.push_back(points);
			}
		}
		CGridMapAligner aligner;
		aligner.setMinLoggingLevel(mrpt::system::LVL_ERROR);
		example_settings(aligner.options, res);
		mrpt::random::getRandomGenerator().randomize(seed);

		for (size_t i = 0; i < maps.size(); i++)
			for (size_t j = i + 1; j < maps.size(); j++)
			{
				const auto t0 = std::chrono::steady_clock::now();
				// (no TReturnInfo asked for: MRPT 2.5.8 copies it through pointers it may leave null)
				auto pdf = aligner.Align(&maps[i], &maps[j], CPose2D(0, 0, 0));
				auto sog = std::dynamic_pointer_cast<mrpt::poses::CPosePDFSOG>(pdf);
				const size_t n = sog ? sog->size() : 0;
				size_t best = 0;
				for (size_t m = 1; m < n; m++)
					if ((*sog)[m].log_w > (*sog)[best].log_w) best = m;
				double good = -1;
				if (n && use_icp) good = icp_goodness(maps[i], maps[j], (*sog)[best].mean);
				const double secs =
					std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
				char line[1024];
				int len = std::snprintf(
					line, sizeof line, "{\"i\": %zu, \"j\": %zu, \"kept\": %s, \"modes\": %zu",
					i, j, n ? "true" : "false", n);
				if (n)
				{
					const auto& g = (*sog)[best];
					len += std::snprintf(
						line + len, sizeof line - len, ", \"pose\": [%.6f, %.6f, %.9f], \"cov\": [",
						g.mean.x(), g.mean.y(), g.mean.phi());
					for (int r = 0; r < 9; r++)
						len += std::snprintf(
							line + len, sizeof line - len, "%s%.9g", r ? ", " : "", g.cov(r / 3, r % 3));
					len += std::snprintf(line + len, sizeof line - len, "]");
				}
				if (good >= 0)
					len += std::snprintf(line + len, sizeof line - len, ", \"icp_goodness\": %.4f", good);
				std::snprintf(line + len, sizeof line - len, ", \"seconds\": %.4f}", secs);
				std::cout << line << std::endl;
			}
	}
	catch (const std::exception& e)
	{
		std::cerr << "mrpt_grid_align: " << mrpt::exception_to_str(e) << "\n";
		return 1;
	}
	// this process's own peak RSS (its parent's rusage would also count the pages of the process
	// it was forked from, before its exec)
	std::ifstream status("/proc/self/status");
	for (std::string line; std::getline(status, line);)
		if (line.rfind("VmHWM:", 0) == 0)
			std::cout << "{\"peak_rss_kb\": " << std::strtol(line.c_str() + 6, nullptr, 10) << "}" << std::endl;
	return 0;
}
