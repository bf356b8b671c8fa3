// m-explore's compositing on poses we give it, so that both mergers composite the same output.
//
// m-explore's own estimate of a configuration may be wrong (on the intel pieces it places maps
// at scales 2.4-4.1 of the reference and tens of metres off), and then its compositing time is
// that of a different output. This driver feeds the maps to m-explore's library
// (combine_grids::MergingPipeline, built by ../shared/peers/mexplore/build.sh) and sets the
// transforms through its public setTransforms, as its node does with known_init_poses, then
// times composeGrids() alone. It is built and run only by the benchmark; nothing of m-explore is
// part of the project.
//
// With --own CONFIDENCE, the poses are ignored and m-explore estimates its own transforms once
// (estimateTransforms(AKAZE, CONFIDENCE), as merge_maps_mexplore does): composeGrids() is then
// timed on its own merge, without its estimation in the same process each time.
// With --serve, the driver sets up once, prints {"ready": true}, then times REPS compositions
// for every line it reads on stdin, until EOF: the benchmark alternates these bursts with ours,
// so that both sides are measured in the same minutes of this noisy VM.
// With --estimate CONFIDENCE (and --serve), a burst is REPS estimateTransforms(AKAZE,
// CONFIDENCE) instead, each a full cycle (m-explore computes every map's features on every
// call), and prints {"estimate_ms": median of REPS}: cold estimation, measured in pairs too.
//
// usage: mexplore_compose [--own CONFIDENCE | --estimate CONFIDENCE] [--serve] REPS pgm res ox oy x y yaw [...]
//   pgm res ox oy   a map_server map (image, metres per cell, origin in metres)
//   x y yaw         pose of that map's frame in the first map's frame (metres, radians)
// prints {"compose_ms": median of REPS, "cells": merged cells, "known": merged known cells}
// per burst
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include <combine_grids/merging_pipeline.h>
#include <geometry_msgs/Transform.h>
#include <nav_msgs/OccupancyGrid.h>
#include <opencv2/imgcodecs.hpp>

namespace {

struct Pose2 {
  double c, s, x, y;  // rotation (cos, sin) and translation of a 2D rigid transform
  Pose2 operator*(const Pose2& b) const {
    return {c * b.c - s * b.s, s * b.c + c * b.s, c * b.x - s * b.y + x, s * b.x + c * b.y + y};
  }
  Pose2 inverse() const { return {c, -s, -(c * x + s * y), s * x - c * y}; }
};

// map_server image -> OccupancyGrid (row 0 of the grid is the image's bottom row), thresholds
// as map_server's defaults: occupied above 0.65, free below 0.196, unknown otherwise.
nav_msgs::OccupancyGrid::Ptr load(const char* pgm, double res, double ox, double oy) {
  cv::Mat img = cv::imread(pgm, cv::IMREAD_GRAYSCALE);
  if (img.empty()) return nullptr;
  nav_msgs::OccupancyGrid::Ptr g(new nav_msgs::OccupancyGrid);
  g->info.resolution = static_cast<float>(res);
  g->info.width = img.cols;
  g->info.height = img.rows;
  g->info.origin.position.x = ox;
  g->info.origin.position.y = oy;
  g->info.origin.orientation.w = 1.0;
  g->data.resize(static_cast<size_t>(img.cols) * img.rows);
  for (int r = 0; r < img.rows; ++r) {
    const uchar* row = img.ptr<uchar>(r);
    signed char* out = &g->data[static_cast<size_t>(img.rows - 1 - r) * img.cols];
    for (int c = 0; c < img.cols; ++c) {
      double occ = (255.0 - row[c]) / 255.0;
      out[c] = occ > 0.65 ? 100 : (occ < 0.196 ? 0 : -1);
    }
  }
  return g;
}

// REPS back-to-back composeGrids(): one JSON line with their median.
void burst(combine_grids::MergingPipeline& pipe, int reps) {
  std::vector<double> ms;
  nav_msgs::OccupancyGrid::Ptr merged;
  for (int i = 0; i < reps; ++i) {
    auto t0 = std::chrono::steady_clock::now();
    merged = pipe.composeGrids();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  size_t known = 0, cells = merged ? merged->data.size() : 0;
  if (merged)
    for (signed char v : merged->data) known += v >= 0;
  printf("{\"compose_ms\": %.3f, \"cells\": %zu, \"known\": %zu}\n", ms[ms.size() / 2], cells, known);
  fflush(stdout);
}

// REPS back-to-back estimateTransforms(), each after feeding the maps again as the peer's own
// merge_maps_mexplore --reps does (feeding not timed): one JSON line with their median.
void estimate_burst(combine_grids::MergingPipeline& pipe, int reps, double confidence,
                    const std::vector<nav_msgs::OccupancyGrid::ConstPtr>& grids) {
  std::vector<double> ms;
  for (int i = 0; i < reps; ++i) {
    pipe.feed(grids.begin(), grids.end());
    auto t0 = std::chrono::steady_clock::now();
    pipe.estimateTransforms(combine_grids::FeatureType::AKAZE, confidence);
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  printf("{\"estimate_ms\": %.3f}\n", ms[ms.size() / 2]);
  fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  bool own = false, serve = false, estimate = false;
  double confidence = 1.0;
  while (argc > 1 && argv[1][0] == '-' && argv[1][1] == '-') {
    if ((!strcmp(argv[1], "--own") || !strcmp(argv[1], "--estimate")) && argc > 2) {
      own = true;
      estimate = !strcmp(argv[1], "--estimate");
      confidence = atof(argv[2]);
      argv += 1;
      argc -= 1;
    } else if (!strcmp(argv[1], "--serve")) {
      serve = true;
    } else {
      break;
    }
    argv += 1;
    argc -= 1;
  }
  if (argc < 9 || (argc - 2) % 7 != 0) {
    fprintf(stderr, "usage: mexplore_compose [--own CONFIDENCE | --estimate CONFIDENCE] [--serve] REPS pgm res ox oy x y yaw [...]\n");
    return 2;
  }
  int reps = std::max(1, atoi(argv[1]));
  std::vector<nav_msgs::OccupancyGrid::ConstPtr> grids;
  std::vector<geometry_msgs::Transform> transforms;
  double res0 = atof(argv[3]);
  // cells of map k -> metres in its frame is (res * cell + origin); m-explore's transform of
  // map k maps the reference's cells to map k's cells: W_k^-1 * P_k^-1 * W_0 (scales cancel).
  Pose2 W0{1, 0, atof(argv[4]) / res0, atof(argv[5]) / res0};
  for (int a = 2; a < argc; a += 7) {
    double res = atof(argv[a + 1]);
    auto g = load(argv[a], res, atof(argv[a + 2]), atof(argv[a + 3]));
    if (!g) {
      fprintf(stderr, "cannot read %s\n", argv[a]);
      return 2;
    }
    if (std::fabs(res - res0) > 1e-9) {
      fprintf(stderr, "maps of different resolutions are not supported here\n");
      return 2;
    }
    double yaw = atof(argv[a + 6]);
    Pose2 P{std::cos(yaw), std::sin(yaw), atof(argv[a + 4]) / res, atof(argv[a + 5]) / res};
    Pose2 Wk{1, 0, atof(argv[a + 2]) / res, atof(argv[a + 3]) / res};
    Pose2 T = Wk.inverse() * P.inverse() * W0;
    geometry_msgs::Transform t;
    double half_turn = std::atan2(T.s, T.c) / 2;
    t.translation.x = T.x;
    t.translation.y = T.y;
    t.rotation.z = std::sin(half_turn);
    t.rotation.w = std::cos(half_turn);
    transforms.push_back(t);
    grids.push_back(g);
  }
  combine_grids::MergingPipeline pipe;
  if (estimate) {   // every burst feeds the maps itself
    printf("{\"ready\": true}\n");
    fflush(stdout);
    std::string line;
    while (std::getline(std::cin, line)) estimate_burst(pipe, reps, confidence, grids);
    return 0;
  }
  pipe.feed(grids.begin(), grids.end());
  if (own) {
    pipe.estimateTransforms(combine_grids::FeatureType::AKAZE, confidence);
  } else if (!pipe.setTransforms(transforms.begin(), transforms.end())) {
    fprintf(stderr, "setTransforms refused the poses\n");
    return 1;
  }
  if (!serve) {
    burst(pipe, reps);
    return 0;
  }
  printf("{\"ready\": true}\n");
  fflush(stdout);
  std::string line;
  while (std::getline(std::cin, line)) burst(pipe, reps);
  return 0;
}
