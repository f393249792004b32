// `pp5echo calibrate SEQ --plus-config CONFIG -o CALIBRATED.xml`: ImageToProbe
// from a recording of an N-wire phantom (docs/calibration.md).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/threads.hpp"
#include "app/commands.hpp"
#include "analysis/probe_calibration.hpp"
#include "analysis/recording.hpp"
#include "core/error.hpp"
#include "formats/image_io.hpp"
#include "core/io_util.hpp"
#include "formats/plus_config.hpp"
#include "formats/sequence_io.hpp"
#include "sim/calibration_sweep.hpp"

namespace pp5::app {
namespace {

using Json = nlohmann::ordered_json;
using calib::Vec2;
using calib::WireSegmentation;

struct Opts {
  std::string sequence, plusConfig, output, validate, images, json, compare, model = "rigid-scale", refine = "all-wires";
  int holdoutEvery = 3, holdoutBlock = 10, threads = 0;
};

// PLUS writes a calibration's Date as month, day, two-digit year, then the time.
std::string plusDate() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%m%d%y_%H%M%S", &tm);
  return buf;
}

// An RGB picture of one frame's segmentation: the frame in grey, the clip
// rectangle (blue), every candidate dot (a yellow ring) and, when found, each
// pattern's line (white) with its dots marked left to right in red, green
// (the middle wire) and blue.
void drawSegmentation(const Frame& f, const WireSegmentation& s, const PlusSegmentation& seg, const std::string& path) {
  const int w = f.width, h = f.height;
  std::vector<std::uint8_t> rgb(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 3);
  for (std::size_t i = 0; i < static_cast<std::size_t>(w) * static_cast<std::size_t>(h); ++i)
    rgb[3 * i] = rgb[3 * i + 1] = rgb[3 * i + 2] = f.u8()[i];
  auto put = [&](int x, int y, std::uint8_t r, std::uint8_t g, std::uint8_t b) {
    if (x < 0 || y < 0 || x >= w || y >= h) return;
    std::uint8_t* p = &rgb[3 * (static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x))];
    p[0] = r, p[1] = g, p[2] = b;
  };
  auto segment = [&](Vec2 a, Vec2 b, std::uint8_t r, std::uint8_t g, std::uint8_t bl) {
    const int n = static_cast<int>(std::ceil(glm::length(b - a))) + 1;
    for (int i = 0; i <= n; ++i) {
      const Vec2 p = a + (b - a) * (static_cast<double>(i) / n);
      put(static_cast<int>(std::lround(p.x)), static_cast<int>(std::lround(p.y)), r, g, bl);
    }
  };
  auto ring = [&](Vec2 c, double radius, std::uint8_t r, std::uint8_t g, std::uint8_t b) {
    for (int i = 0; i < 64; ++i) {
      const double a = i * 2.0 * 3.14159265358979 / 64.0;
      put(static_cast<int>(std::lround(c.x + radius * std::cos(a))), static_cast<int>(std::lround(c.y + radius * std::sin(a))), r, g, b);
    }
  };
  const Vec2 o(seg.clipRectangleOrigin), sz(seg.clipRectangleSize.x > 0 ? seg.clipRectangleSize.x : w,
                                             seg.clipRectangleSize.y > 0 ? seg.clipRectangleSize.y : h);
  segment(o, o + Vec2(sz.x, 0), 60, 90, 200);
  segment(o + Vec2(sz.x, 0), o + sz, 60, 90, 200);
  segment(o + sz, o + Vec2(0, sz.y), 60, 90, 200);
  segment(o + Vec2(0, sz.y), o, 60, 90, 200);
  for (const auto& c : s.candidates) ring(c.position, 9.0, 230, 200, 0);
  for (const auto& p : s.patterns) {
    segment(p[0], p[2], 255, 255, 255);
    const std::uint8_t col[3][3] = {{255, 40, 40}, {40, 255, 40}, {60, 120, 255}};
    for (int i = 0; i < 3; ++i)
      for (double r : {5.0, 6.0}) ring(p[static_cast<std::size_t>(i)], r, col[i][0], col[i][1], col[i][2]);
  }
  writeRgbPng(path, w, h, rgb.data());
}

Json errorJson(const calib::ReprojectionError& e) {
  Json j;
  j["points"] = e.points;
  j["mean_mm"] = e.mean;
  j["sd_mm"] = e.sd;
  j["rms_mm"] = e.rms;
  j["max_mm"] = e.max;
  j["mean_per_pattern_mm"] = e.meanPerPattern;
  return j;
}

std::string errorLine(const calib::ReprojectionError& e) {
  std::string per;
  for (double m : e.meanPerPattern) per += fmt::format("{}{:.3f}", per.empty() ? "" : ", ", m);
  return fmt::format("{:.3f} mm mean, {:.3f} sd, {:.3f} max over {} points (per pattern: {})", e.mean, e.sd, e.max,
                     e.points, per);
}

calib::SegmentedRecording segmentWithProgress(const std::string& path, const PlusConfig& cfg, int threads,
                                              const std::function<void(const Frame&, const WireSegmentation&)>& onFrame) {
  const auto start = std::chrono::steady_clock::now();
  // On a terminal the count rewrites one line; in a log, a line per quarter.
  const bool tty = isatty(fileno(stderr));
  std::size_t nextQuarter = 1;
  const std::string name = std::filesystem::path(path).filename().string();
  auto rec = calib::segmentRecording(path, cfg, threads, onFrame, [&](std::size_t done, std::size_t total) {
    if (tty) {
      std::fprintf(stderr, "\rsegmenting %s: %zu/%zu frames", name.c_str(), done, total);
    } else if (total > 0 && done * 4 >= nextQuarter * total) {
      std::fprintf(stderr, "segmenting %s: %zu/%zu frames\n", name.c_str(), done, total);
      while (done * 4 >= nextQuarter * total) ++nextQuarter;
    }
    std::fflush(stderr);
  });
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (tty) std::fprintf(stderr, "\n");
  fmt::print("{}: the pattern found in {} of {} frames ({:.1f} s)\n", path, rec.found.size(), rec.frames, s);
  return rec;
}

// The most common reasons frames were left out, for the error and the report.
std::string missedSummary(const calib::SegmentedRecording& rec) {
  std::map<std::string, int> why;
  for (const auto& [i, w] : rec.missed) ++why[w.substr(0, w.find(':') == std::string::npos ? w.size() : w.find(':'))];
  std::string s;
  for (const auto& [w, n] : why) s += fmt::format("{}{} frames: {}", s.empty() ? "" : "; ", n, w);
  if (!rec.missed.empty()) s += fmt::format(" (first: frame {}, {})", rec.missed.front().first, rec.missed.front().second);
  return s;
}

// An output's folder must exist before any work is done, so a typo does not
// cost the whole calibration or leave some outputs written and others not.
void checkOutputFolder(const std::string& path) {
  if (path.empty()) return;
  const std::filesystem::path dir = std::filesystem::absolute(path).parent_path();
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) inputError(path, "cannot write: the folder '{}' does not exist", dir.string());
}

int runCalibrate(const Opts& o) {
  // Block b is held out when b % N == N - 1: with N = 1, every block.
  if (o.holdoutEvery == 1)
    throw InputError("--holdout-every 1 holds every block of frames out of the fit, leaving none to fit: give 0 to fit "
                     "every frame, or 2 and up to hold out every Nth block");
  const PlusConfig cfg = readPlusConfig(o.plusConfig);
  const calib::NWirePhantom phantom = calib::phantomOf(cfg);
  checkOutputFolder(o.output);
  checkOutputFolder(o.json);
  if (!o.images.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(o.images, ec);
    if (ec || !std::filesystem::is_directory(o.images))
      inputError(o.images, "cannot create the folder for --images: {}", ec ? ec.message() : "not a folder");
  }

  std::size_t drawn = 0;
  auto draw = [&](const Frame& f, const WireSegmentation& s) {
    if (o.images.empty()) return;
    drawSegmentation(f, s, *cfg.segmentation,
                     fmt::format("{}/frame_{:04d}_{}.png", o.images, f.index, s.found ? "found" : "missed"));
    ++drawn;
  };
  const auto rec = segmentWithProgress(o.sequence, cfg, o.threads, draw);
  if (!o.images.empty()) fmt::print("wrote {} segmentation images to {}\n", drawn, o.images);
  calib::CalibrationOptions co;
  co.model = o.model == "rigid-scale" ? calib::CalibrationModel::RigidScale : calib::CalibrationModel::Affine;
  co.refinement = o.refine == "none"        ? calib::CalibrationRefinement::None
                  : o.refine == "all-wires" ? calib::CalibrationRefinement::AllWires
                                            : calib::CalibrationRefinement::MeanDistance;
  if (static_cast<int>(rec.found.size()) < co.minFrames)
    inputError(o.sequence,
               "the N-wire pattern of {} was found in {} of {} frames, fewer than the {} a calibration needs: is this "
               "a recording of that phantom? {}",
               o.plusConfig, rec.found.size(), rec.frames, co.minFrames, missedSummary(rec));
  if (!rec.missed.empty()) fmt::print("frames left out: {}\n", missedSummary(rec));

  // Frames held out of the fit: every holdoutEvery-th block of holdoutBlock
  // consecutive frames (neighbouring frames are nearly the same pose, so
  // holding out single frames would flatter the figure).
  std::vector<calib::CalibrationFrame> fit, held;
  for (const auto& f : rec.found) {
    const bool out = o.holdoutEvery > 0 &&
                     (f.frameIndex / static_cast<std::size_t>(o.holdoutBlock)) % static_cast<std::size_t>(o.holdoutEvery) ==
                         static_cast<std::size_t>(o.holdoutEvery - 1);
    (out ? held : fit).push_back(f);
  }
  if (static_cast<int>(fit.size()) < co.minFrames)
    inputError(o.sequence,
               "the pattern was found in {} frames, but --holdout-every {} with --holdout-block {} holds {} of them "
               "out, leaving {} to fit, fewer than the {} a calibration needs",
               rec.found.size(), o.holdoutEvery, o.holdoutBlock, held.size(), fit.size(), co.minFrames);
  const calib::CalibrationResult res = calib::calibrateProbe(phantom, fit, co);

  Json j;
  j["sequence"] = o.sequence;
  j["plus_config"] = o.plusConfig;
  j["model"] = o.model;
  j["refinement"] = o.refine;
  j["frames"] = rec.frames;
  j["frames_found"] = rec.found.size();
  j["frames_fitted"] = fit.size();
  j["frames_held_out"] = held.size();
  j["wire0_on_right"] = res.wire0OnRight;
  j["points_rejected"] = res.pointsRejected;
  j["dots_rejected"] = res.dotsRejected;
  j["condition_number"] = res.conditionNumber;
  j["rotation_spread_deg"] = res.rotationSpreadDeg;
  j["translation_spread_mm"] = res.translationSpreadMm;
  j["image_to_probe"] = toRowMajor(res.imageToProbe);
  j["linear_fit_error"] = errorJson(res.linearError);
  j["calibration_error"] = errorJson(res.error);
  j["wire_distance_rms_mm"] = res.wireDistanceRms;

  fmt::print("fitted {} frames, held out {}; outliers: {} of {} middle-wire points in the linear fit, {} of {} dots "
             "in the refinement\n",
             fit.size(), held.size(), res.pointsRejected, fit.size() * static_cast<std::size_t>(phantom.patternCount()),
             res.dotsRejected, co.refinement == calib::CalibrationRefinement::AllWires ? fit.size() * 3 * static_cast<std::size_t>(phantom.patternCount()) : 0);
  fmt::print("probe motion: turned up to {:.1f} degrees, moved up to {:.1f} mm; condition number {:.1f}\n",
             res.rotationSpreadDeg, res.translationSpreadMm, res.conditionNumber);
  fmt::print("ImageToProbe ({}, refinement {}):\n", o.model, o.refine);
  const auto rm = toRowMajor(res.imageToProbe);
  for (int r = 0; r < 3; ++r)
    fmt::print("  {:12.6f} {:12.6f} {:12.6f} {:12.4f}\n", rm[4 * r], rm[4 * r + 1], rm[4 * r + 2], rm[4 * r + 3]);
  fmt::print("mm per pixel: {:.5f} x {:.5f}\n", glm::length(glm::dvec3(res.imageToProbe[0])),
             glm::length(glm::dvec3(res.imageToProbe[1])));
  fmt::print("3D reprojection error of the middle wires (PLUS's figure):\n");
  fmt::print("  linear fit, fitted frames: {}\n", errorLine(res.linearError));
  fmt::print("  final, fitted frames:      {}\n", errorLine(res.error));
  fmt::print("  every dot's RMS distance from its wire, fitted frames: {:.3f} mm\n", res.wireDistanceRms);
  // Per wire: the mean distance of its dots from their line (outer wires) or
  // ratio point (middle wires).
  auto perWire = [&](const std::vector<calib::CalibrationFrame>& frames, const char* label, const char* key) {
    const auto w = calib::wireErrors(phantom, frames, res.imageToProbe, res.wire0OnRight);
    std::string line;
    Json jw = Json::object();
    for (int k = 0; k < phantom.patternCount(); ++k)
      for (int i = 0; i < 3; ++i) {
        const std::string& name = phantom.pattern(k).wires[static_cast<std::size_t>(i)].name;
        const double v = w[static_cast<std::size_t>(3 * k + i)];
        line += fmt::format("{}{} {:.3f}", line.empty() ? "" : ", ", name, v);
        jw[name] = v;
      }
    fmt::print("  per wire, {} (mm): {}\n", label, line);
    j[key] = jw;
  };
  perWire(fit, "fitted frames", "per_wire_fitted_mm");
  if (!held.empty()) perWire(held, "held-out frames", "per_wire_held_out_mm");
  if (!held.empty()) {
    const auto e = calib::middleWireError(phantom, held, res.imageToProbe, res.wire0OnRight);
    fmt::print("  final, held-out frames:    {}\n", errorLine(e));
    j["held_out_error"] = errorJson(e);
  }
  if (!held.empty()) {
    const auto e = calib::middleWireError(phantom, held, res.linearImageToProbe, res.wire0OnRight);
    j["held_out_linear_fit_error"] = errorJson(e);
    fmt::print("  linear fit, held-out frames: {}\n", errorLine(e));
  }
  std::vector<calib::CalibrationFrame> validation;
  if (!o.validate.empty()) {
    const auto vrec = segmentWithProgress(o.validate, cfg, o.threads, {});
    if (vrec.found.empty())
      inputError(o.validate, "the N-wire pattern was found in none of its {} frames: {}", vrec.frames,
                 missedSummary(vrec));
    const auto e = calib::middleWireError(phantom, vrec.found, res.imageToProbe, res.wire0OnRight);
    fmt::print("  final, {}: {}\n", o.validate, errorLine(e));
    validation = vrec.found;
    j["validation_sequence"] = o.validate;
    j["validation_frames_found"] = vrec.found.size();
    j["validation_error"] = errorJson(e);
  }

  if (!o.compare.empty()) {
    // Another calibration (the config's own, or PLUS's) scored on the same frames.
    const PlusConfig other = readPlusConfig(o.compare);
    const auto m = other.coordinates.get(cfg.probeCalibrationFrames.image, cfg.probeCalibrationFrames.probe);
    if (!m)
      inputError(o.compare, "no {}To{} transform to compare with", cfg.probeCalibrationFrames.image,
                 cfg.probeCalibrationFrames.probe);
    Json c;
    c["config"] = o.compare;
    c["corner_distance_mm"] = calib::cornerDistanceMm(*m, res.imageToProbe, rec.width, rec.height);
    c["linear_fit_corner_distance_mm"] = calib::cornerDistanceMm(*m, res.linearImageToProbe, rec.width, rec.height);
    const auto fitted = calib::middleWireError(phantom, fit, *m, res.wire0OnRight);
    c["fitted_error"] = errorJson(fitted);
    fmt::print("{}'s {}To{}: corners and centre up to {:.3f} mm from this one's\n", o.compare,
               cfg.probeCalibrationFrames.image, cfg.probeCalibrationFrames.probe, c["corner_distance_mm"].get<double>());
    fmt::print("  (the linear fit's: up to {:.3f} mm)\n", c["linear_fit_corner_distance_mm"].get<double>());
    fmt::print("  on the fitted frames:   {}\n", errorLine(fitted));
    if (!held.empty()) {
      const auto e = calib::middleWireError(phantom, held, *m, res.wire0OnRight);
      c["held_out_error"] = errorJson(e);
      fmt::print("  on the held-out frames: {}\n", errorLine(e));
    }
    if (!validation.empty()) {
      const auto e = calib::middleWireError(phantom, validation, *m, res.wire0OnRight);
      c["validation_error"] = errorJson(e);
      fmt::print("  on {}: {}\n", o.validate, errorLine(e));
    }
    j["compared"] = c;
  }

  const auto& fr = cfg.probeCalibrationFrames;
  writePlusConfigWithTransform(o.plusConfig, o.output, {fr.image, fr.probe, res.imageToProbe}, res.error.mean, plusDate());
  fmt::print("wrote {} (the config with {}To{} set)\n", o.output, fr.image, fr.probe);

  if (!o.json.empty()) {
    io::AtomicFile out(o.json);
    out.write(j.dump(2) + "\n");
    out.commit();
  }
  return 0;
}

}  // namespace

void addSimulateCalibrationCommand(CLI::App& app, int& exitCode) {
  struct SimOpts {
    std::string plusConfig, output, truth;
    sim::CalibrationSweepSettings s;
    int threads = 0;
  };
  auto o = std::make_shared<SimOpts>();
  CLI::App* cmd = app.add_subcommand(
      "simulate-calibration",
      "Simulate a tracked recording of a config's N-wire phantom with a known ImageToProbe (for `calibrate`)");
  cmd->add_option("--plus-config", o->plusConfig, "PLUS config with PhantomDefinition and Phantom to Reference")
      ->required();
  cmd->add_option("-o,--output", o->output, "The recording (.igs.mha or .igs.nrrd)")->required();
  cmd->add_option("--truth", o->truth, "Write the config with the true Image to Probe transform here")->required();
  cmd->add_option("--seed", o->s.seed, "Seed of the speckle, the noise and the probe's path");
  cmd->add_option("--frames", o->s.frames, "Frames")->check(CLI::Range(1, 100000));
  cmd->add_option("--tracker-noise-mm", o->s.trackerNoiseMm, "Tracker noise, sd of each translation (mm)")
      ->check(CLI::Range(0.0, 100.0));
  cmd->add_option("--tracker-noise-deg", o->s.trackerNoiseDeg, "Tracker noise, sd of each rotation (degrees)")
      ->check(CLI::Range(0.0, 45.0));
  cmd->add_option("--threads", o->threads, "Threads (0 = every core)")->check(CLI::Range(0, kMaxThreads));
  cmd->callback([o, &exitCode] {
    const PlusConfig cfg = readPlusConfig(o->plusConfig);
    if (!cfg.calibrationError.empty()) throw InputError(cfg.calibrationError);
    if (!cfg.phantomDefinition) inputError(o->plusConfig, "no <PhantomDefinition>: nothing to simulate");
    checkOutputFolder(o->output);
    checkOutputFolder(o->truth);
    const auto& fr = cfg.probeCalibrationFrames;
    const auto phantomToReference = cfg.coordinates.get(fr.phantom, fr.reference);
    if (!phantomToReference) inputError(o->plusConfig, "no {}To{} transform: the phantom has no place", fr.phantom, fr.reference);
    fmt::print("simulating {} frames of {}'s phantom (seed {})...\n", o->s.frames, o->plusConfig, o->s.seed);
    const auto sweep = sim::simulateCalibrationSweep(*cfg.phantomDefinition, *phantomToReference, o->s, o->threads);
    writeAllFrames(o->output, sweep.frames);
    writePlusConfigWithTransform(o->plusConfig, o->truth, {fr.image, fr.probe, sweep.imageToProbe}, 0.0, plusDate());
    fmt::print("wrote {} ({} frames, {:.4f} mm per pixel) and {} (the true {}To{})\n", o->output, sweep.frames.size(),
               sweep.mmPerPixel, o->truth, fr.image, fr.probe);
    exitCode = 0;
  });
}

void addCalibrateCommand(CLI::App& app, int& exitCode) {
  auto o = std::make_shared<Opts>();
  CLI::App* cmd = app.add_subcommand(
      "calibrate", "Probe calibration (ImageToProbe) from a tracked recording of an N-wire phantom, as PLUS's fCal");
  cmd->add_option("SEQUENCE", o->sequence, "PLUS sequence of the phantom (8-bit B-mode, tracked)")->required();
  cmd->add_option("--plus-config", o->plusConfig,
                  "PLUS config with PhantomDefinition, Segmentation and the Phantom's place (PhantomToReference)")
      ->required();
  cmd->add_option("-o,--output", o->output, "The config written back with the new Image to Probe transform")->required();
  cmd->add_option("--validate", o->validate, "Another recording of the phantom to score the calibration on");
  cmd->add_option("--compare", o->compare,
                  "A config whose Image to Probe transform is scored on the same frames (the old calibration, or PLUS's)");
  cmd->add_option("--images", o->images, "Write a PNG of each frame's segmentation to this folder");
  cmd->add_option("--json", o->json, "Write the report as JSON to this file");
  cmd->add_option("--model", o->model, "rigid-scale (a rotation, a translation and a scale per image axis) or affine (a 3x4 on the image plane, as PLUS)")
      ->check(CLI::IsMember({"affine", "rigid-scale"}));
  cmd->add_option("--refine", o->refine,
                  "After the linear fit, minimise: all-wires (every dot's squared distance from its wire's line, "
                  "the middle dots' from their ratio points), mean (the mean 3D reprojection error of the middle "
                  "wires) or none")
      ->check(CLI::IsMember({"mean", "all-wires", "none"}));
  cmd->add_option("--holdout-every", o->holdoutEvery,
                  "Hold out every Nth block of frames from the fit to score it (0 = fit every frame)")
      ->check(CLI::Range(0, 1000));
  cmd->add_option("--holdout-block", o->holdoutBlock, "Frames per hold-out block")->check(CLI::Range(1, 100000));
  cmd->add_option("--threads", o->threads, "Threads for the segmentation (0 = every core)")->check(CLI::Range(0, kMaxThreads));
  cmd->callback([o, &exitCode] { exitCode = runCalibrate(*o); });
}

}  // namespace pp5::app
