// Drives rbpf_slam's GyroScaleEstimator (src/rbpf_slam/gyro_scale.cpp) over steps read from stdin,
// for test_gyro_scale.py: argv enabled limit window prior_sigma; each stdin line "odometry_turn
// match_turn" (rad) prints the factor applied after it; the last line: "final applied estimate
// used rejected updates".
#include "gyro_scale.h"

#include <cstdio>
#include <cstdlib>

int main(int argc, char** argv)
{
	if (argc != 5)
	{
		std::fprintf(stderr, "usage: gyro_scale_check ENABLED LIMIT WINDOW PRIOR_SIGMA < steps\n");
		return 2;
	}
	rbpf_slam::GyroScaleOptions o;
	o.enabled = std::atoi(argv[1]) != 0;
	o.limit = std::atof(argv[2]);
	o.window = std::atof(argv[3]);
	o.priorSigma = std::atof(argv[4]);
	rbpf_slam::GyroScaleEstimator estimator(o);
	double odometryTurn, matchTurn;
	while (std::scanf("%lf %lf", &odometryTurn, &matchTurn) == 2)
	{
		estimator.addStep(odometryTurn, matchTurn);
		std::printf("%.9f\n", estimator.scale());
	}
	std::printf(
		"final %.9f %.9f %llu %llu %llu\n", estimator.scale(), estimator.estimate(),
		static_cast<unsigned long long>(estimator.stepsUsed()),
		static_cast<unsigned long long>(estimator.stepsRejected()),
		static_cast<unsigned long long>(estimator.updates()));
	return 0;
}
