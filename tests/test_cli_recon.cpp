// `pp5echo reconstruct` and `pp5echo evaluate`, end to end, on a small
// simulated sweep: what they write and report, and how they refuse bad input.
#include <gtest/gtest.h>

#include "cli_test_util.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/wait.h>

#include <fmt/format.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "formats/sequence_io.hpp"
#include "formats/volume_io.hpp"

namespace {

namespace fs = std::filesystem;

using Result = pp5::test::CliResult;
using pp5::test::run;

nlohmann::json readJson(const fs::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}

// A small doll sweep (8 frames of 64 x 96 pixels), simulated once.
class ReconCli : public ::testing::Test {
protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() / ("pp5cli-recon-" + std::to_string(::getpid())));
    fs::remove_all(*dir_);
    fs::create_directories(*dir_);
    const Result r = run("simulate " + std::string(PP5_SOURCE_DIR) + "/configs/doll.toml -o " + dir_->string() +
                         " --set sim.sweep.max_frames=8 --set sim.probe.width_px=64 --set sim.probe.height_px=96"
                         " --set output.preview_frames=0 --set grid.spacing=[2,2,2]");
    ASSERT_EQ(r.status, 0) << r.out;
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
  }
  static fs::path dir() { return *dir_; }
  static std::string seq() { return (*dir_ / "doll_sweep.igs.mha").string(); }
  static std::string xml() { return (*dir_ / "doll_config.xml").string(); }
  static std::string toml() { return (fs::path(PP5_SOURCE_DIR) / "configs" / "doll.toml").string(); }
  static fs::path* dir_;
};
fs::path* ReconCli::dir_ = nullptr;

TEST_F(ReconCli, WritesTheVolumeAndTheWeightsAndReportsTheFrames) {
  const fs::path vol = dir() / "v.mha", w = dir() / "w.nrrd";
  const Result r = run("reconstruct " + seq() + " --plus-config " + xml() + " -c " + toml() +
                       " --set grid.spacing=[2,2,2] -o " + vol.string() + " --weights " + w.string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("reconstructed 8 of 8 frames"), std::string::npos) << r.out;
  const pp5::Volume v = pp5::readVolume(vol.string()), wv = pp5::readVolume(w.string());
  EXPECT_EQ(v.grid.dims, wv.grid.dims);
  EXPECT_DOUBLE_EQ(v.grid.spacing.x, 2.0);
  std::size_t covered = 0;
  for (std::size_t i = 0; i < wv.grid.voxelCount(); ++i) covered += wv.value(i) > 0.0 ? 1 : 0;
  EXPECT_GT(covered, wv.grid.voxelCount() / 4);
}

TEST_F(ReconCli, InvalidFramesAreSkippedAndCounted) {
  std::vector<pp5::Frame> frames = pp5::readAllFrames(seq());
  ASSERT_EQ(frames.size(), 8u);
  frames[1].imageValid = false;
  frames[4].imageValid = false;
  const fs::path bad = dir() / "two_invalid.igs.mha";
  pp5::writeAllFrames(bad.string(), frames);
  const Result r = run("reconstruct " + bad.string() + " --plus-config " + xml() + " -c " + toml() +
                       " --set grid.spacing=[2,2,2] -o " + (dir() / "v2.mha").string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("reconstructed 6 of 8 frames"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("skipped 2 (2 INVALID status"), std::string::npos) << r.out;

  // Every frame INVALID: nothing to place is an error, not an empty volume.
  for (auto& f : frames) f.imageValid = false;
  const fs::path none = dir() / "all_invalid.igs.mha";
  pp5::writeAllFrames(none.string(), frames);
  const fs::path out = dir() / "v3.mha";
  const Result e = run("reconstruct " + none.string() + " --plus-config " + xml() + " -o " + out.string());
  EXPECT_EQ(e.status, 1) << e.out;
  EXPECT_NE(e.out.find("none of its 8 frames can be placed"), std::string::npos) << e.out;
  EXPECT_FALSE(fs::exists(out));
}

// A fixed grid that misses the phantom samples one value everywhere: the
// truth volume is still written, with a warning naming the grid.
TEST_F(ReconCli, SimulateSaysWhenTheGridMissesThePhantom) {
  const fs::path far = dir() / "far";
  const Result r = run("simulate " + toml() + " -o " + far.string() +
                       " --set sim.sweep.max_frames=2 --set sim.probe.width_px=32 --set sim.probe.height_px=32"
                       " --set output.preview_frames=0 --set grid.auto_extent=false --set 'grid.origin=[5000,5000,5000]'"
                       " --set 'grid.dims=[8,8,8]'");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("does not reach the phantom's structures"), std::string::npos) << r.out;
  const Result near = run("simulate " + toml() + " -o " + (dir() / "near").string() +
                          " --set sim.sweep.max_frames=2 --set sim.probe.width_px=32 --set sim.probe.height_px=32"
                          " --set output.preview_frames=0 --set grid.spacing=[4,4,4]");
  EXPECT_EQ(near.status, 0) << near.out;
  EXPECT_EQ(near.out.find("does not reach the phantom"), std::string::npos) << near.out;
}

TEST_F(ReconCli, AnEmptySequenceIsAnError) {
  // The simulated file's header with no frames at all.
  std::ifstream in(seq(), std::ios::binary);
  std::string header, line;
  while (std::getline(in, line)) {
    if (line.rfind("DimSize", 0) == 0) line = "DimSize = 64 96 0";
    if (line.rfind("CompressedData ", 0) == 0) line = "CompressedData = False";
    if (line.rfind("CompressedDataSize", 0) == 0 || line.rfind("Seq_Frame", 0) == 0) continue;
    header += line + "\n";
    if (line.rfind("ElementDataFile", 0) == 0) break;
  }
  const fs::path empty = dir() / "empty.igs.mha";
  std::ofstream(empty, std::ios::binary) << header;
  const fs::path out = dir() / "v4.mha";
  const Result r = run("reconstruct " + empty.string() + " --plus-config " + xml() + " -o " + out.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("no frames"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(out));
}

TEST_F(ReconCli, AGridTooLargeIsRefusedBeforeAllocating) {
  const fs::path out = dir() / "huge.mha";
  const Result r = run("reconstruct " + seq() + " --plus-config " + xml() + " -c " + toml() +
                       " --set grid.spacing=[0.001,0.001,0.001] -o " + out.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("use a coarser spacing"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(out));
}

TEST_F(ReconCli, EvaluateTruthAndLeaveOutWriteTheirFigures) {
  const fs::path tj = dir() / "truth.json";
  const Result t = run("evaluate truth " + seq() + " --plus-config " + xml() + " -c " + toml() + " --truth " +
                       (dir() / "doll_truth.mha").string() + " --json " + tj.string());
  ASSERT_EQ(t.status, 0) << t.out;
  const auto j = readJson(tj);
  EXPECT_EQ(j["protocol"], "truth");
  EXPECT_EQ(j["frames_inserted"], 8);
  EXPECT_GT(j["voxels_compared"].get<double>(), 0.0);
  EXPECT_GE(j["voxels_compared"].get<double>(), j["tissue_voxels_compared"].get<double>());
  EXPECT_TRUE(std::isfinite(j["rmse"].get<double>()));
  EXPECT_GT(j["rmse"].get<double>(), 0.0);
  EXPECT_GT(j["rmse_tissue"].get<double>(), 0.0);
  EXPECT_NE(t.out.find("RMSE, tissue"), std::string::npos);

  const fs::path lj = dir() / "leave.json";
  const Result l = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
                       " --keep-every 2 --json " + lj.string());
  ASSERT_EQ(l.status, 0) << l.out;
  const auto k = readJson(lj);
  EXPECT_EQ(k["frames_kept"], 4);
  EXPECT_EQ(k["frames_held_out"], 4);
  EXPECT_GT(k["pixels_compared"].get<double>(), 0.0);
  EXPECT_GT(k["rmse"].get<double>(), 0.0);
  EXPECT_GE(k["rmse"].get<double>(), k["mae"].get<double>());
  // The compared fraction beside every error (issue 18): in the JSON and on both error lines.
  const double compared = k["pixels_compared"].get<double>(), skipped = k["pixels_skipped"].get<double>();
  EXPECT_DOUBLE_EQ(k["compared_fraction"].get<double>(), compared / (compared + skipped));
  const std::string pct = fmt::format("({:.1f}% of pixels compared)", 100.0 * compared / (compared + skipped));
  EXPECT_NE(l.out.find("MAE               " + fmt::format("{:.3f}", k["mae"].get<double>()) + " grey levels " + pct),
            std::string::npos)
      << l.out;
  EXPECT_NE(l.out.find("RMSE              " + fmt::format("{:.3f}", k["rmse"].get<double>()) + " grey levels " + pct),
            std::string::npos)
      << l.out;
}

// The sequence with frame 3's ProbeToTrackerTransform replaced (the header is
// text; the pixels follow it unchanged).
fs::path withFrame3Pose(const fs::path& seqPath, const fs::path& out, const std::string& matrix) {
  std::ifstream in(seqPath, std::ios::binary);
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string key = "Seq_Frame0003_ProbeToTrackerTransform = ";
  const auto at = s.find(key);
  EXPECT_NE(at, std::string::npos);
  const auto end = s.find('\n', at);
  s.replace(at + key.size(), end - at - key.size(), matrix);
  std::ofstream(out, std::ios::binary) << s;
  return out;
}

// Poses no method can use are refused by every command, naming the frame
// (issue 20): `reconstruct` took an all-zero pose that `run` refused, an
// outlier was blamed on the grid's spacing, and a 1e300 pose overflowed an
// integer conversion.
TEST_F(ReconCli, BadPosesAreRefusedNamingTheFrame) {
  const fs::path zero = withFrame3Pose(seq(), dir() / "zero.igs.mha", "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0");
  Result r = run("reconstruct " + zero.string() + " --plus-config " + xml() + " -o " + (dir() / "z.mha").string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("frame 3"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir() / "z.mha"));
  // The same frame held out of a leave-out (it was scored, and the grid
  // stretched to reach it).
  r = run("evaluate leave-out " + zero.string() + " --plus-config " + xml() + " --keep-every 2");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("frame 3"), std::string::npos) << r.out;
  for (const char* far : {"1e6", "1e300"}) {
    const fs::path f = withFrame3Pose(seq(), dir() / "far.igs.mha",
                                      std::string("0 0 1 ") + far + " -1 0 0 150 0 -1 0 180 0 0 0 1");
    r = run("reconstruct " + f.string() + " --plus-config " + xml() + " -c " + toml() + " -o " +
            (dir() / "f.mha").string());
    EXPECT_EQ(r.status, 1) << far << ": " << r.out;
    EXPECT_NE(r.out.find("frame 3: its image lies"), std::string::npos) << far << ": " << r.out;
    EXPECT_EQ(r.out.find("coarser spacing"), std::string::npos) << far << ": " << r.out;
  }
}

// A header field in another encoding than UTF-8: `info` still describes the
// file, shows those bytes as U+FFFD and names the file (it failed with a bare
// JSON library message, issue 20 item 7).
TEST_F(ReconCli, InfoShowsAHeaderThatIsNotUtf8AndNamesIt) {
  std::ifstream in(seq(), std::ios::binary);
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string from = "UltrasoundImageType = BRIGHTNESS";
  const auto at = s.find(from);
  ASSERT_NE(at, std::string::npos);
  s.replace(at, from.size(), "UltrasoundImageType = BRIGHT\xff\xfeNESS");
  const fs::path bad = dir() / "latin.igs.mha";
  std::ofstream(bad, std::ios::binary) << s;
  const Result r = run("info " + bad.string());
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find(bad.string() + ": the header holds bytes that are not UTF-8"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("BRIGHT\xef\xbf\xbd\xef\xbf\xbdNESS"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("json.exception"), std::string::npos) << r.out;
  // The warning goes to stderr: stdout is the JSON alone (`info f | jq` works).
  const Result stdoutOnly = run("info " + bad.string() + " 2>/dev/null | cat");
  ASSERT_FALSE(stdoutOnly.out.empty());
  EXPECT_EQ(stdoutOnly.out.front(), '{') << stdoutOnly.out;
  EXPECT_EQ(stdoutOnly.out.find("not UTF-8"), std::string::npos) << stdoutOnly.out;
}

// An error over nothing is refused, never reported as a perfect score
// (issue 20): a truth volume elsewhere in space, one with a NaN voxel, a
// leave-out whose held-out pixels have no value all around them.
// --held-out-in-volume: the held-out frames are inserted too and still scored,
// which can only bring the volume closer to them.
TEST_F(ReconCli, LeaveOutWithTheHeldOutFramesInTheVolumeComesCloser) {
  const fs::path a = dir() / "leave_a.json", b = dir() / "leave_b.json";
  Result r = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
                 " --keep-every 2 --json " + a.string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(r.out.find("what the grid holds of them, not a leave-out"), std::string::npos) << r.out;
  r = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
          " --keep-every 2 --held-out-in-volume --json " + b.string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("what the grid holds of them, not a leave-out"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("8 inserted, 4 of them scored"), std::string::npos) << r.out;
  const auto out = readJson(a), in = readJson(b);
  EXPECT_FALSE(out["held_out_in_volume"].get<bool>());
  EXPECT_TRUE(in["held_out_in_volume"].get<bool>());
  EXPECT_EQ(out["frames_kept"], 4);
  EXPECT_EQ(in["frames_kept"], 8);
  EXPECT_EQ(in["frames_held_out"], 4);
  EXPECT_LT(in["rmse"].get<double>(), out["rmse"].get<double>());
}

// `evaluate speckle`: the resolution cell and the frame spacing, and a clear
// refusal where there is no pair of frames to difference.
TEST_F(ReconCli, EvaluateSpeckleMeasuresTheFramesAndRefusesASingleFrame) {
  const fs::path js = dir() / "speckle.json";
  Result r = run("evaluate speckle " + seq() + " --plus-config " + xml() + " -c " + toml() + " --json " + js.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto j = readJson(js);
  EXPECT_EQ(j["protocol"], "speckle");
  EXPECT_GE(j["pairs"].get<int>(), 1);
  EXPECT_LE(j["pairs"].get<int>(), 7);  // 8 frames
  EXPECT_NEAR(j["pixel_mm"][0].get<double>(), 98.0 / 64.0, 1e-6);  // paper35's 98 mm over 64 pixels
  EXPECT_NEAR(j["frame_spacing_mm"].get<double>(), 2.0, 0.2);       // captured every 2 mm
  ASSERT_TRUE(j["lateral_px"].is_number()) << r.out;
  EXPECT_NEAR(j["lateral_mm"].get<double>(), j["lateral_px"].get<double>() * j["pixel_mm"][0].get<double>(), 1e-9);
  EXPECT_DOUBLE_EQ(j["autocorrelation_lateral"][0].get<double>(), 1.0);
  EXPECT_NE(r.out.find("lateral (x)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("frame spacing"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("  elevation  "), std::string::npos) << r.out;
  EXPECT_TRUE(j.contains("elevation_mm") && j.contains("elevation_variance_ratio")) << r.out;
  EXPECT_LE(j["triples"].get<int>(), 6);  // 8 frames
  // The suggested kernel, as --set flags to copy.
  ASSERT_TRUE(j["suggested_kernel_mm"].is_array()) << r.out;
  EXPECT_NEAR(j["suggested_kernel_mm"][2].get<double>(), 1.5 * j["frame_spacing_mm"].get<double>(), 1e-9);
  EXPECT_NE(r.out.find(fmt::format("--set recon.kernel_elevation_mm={:.2f}", j["suggested_kernel_mm"][2].get<double>())),
            std::string::npos)
      << r.out;

  const fs::path one = dir() / "one";
  r = run("simulate " + toml() + " -o " + one.string() +
          " --set sim.sweep.max_frames=1 --set sim.probe.width_px=64 --set sim.probe.height_px=96"
          " --set output.preview_frames=0");
  ASSERT_EQ(r.status, 0) << r.out;
  r = run("evaluate speckle " + (one / "doll_sweep.igs.mha").string() + " --plus-config " +
          (one / "doll_config.xml").string() + " -c " + toml());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("no two consecutive frames"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("lateral (x)"), std::string::npos) << r.out;
}

// recon.kernel_from_frames: the kernel `evaluate speckle` suggests is the one
// `reconstruct` uses (the same volume, voxel for voxel, as that kernel set by
// hand), a half-width set by hand wins, a leave-out derives it from the kept
// frames alone, and what cannot use it refuses it.
TEST_F(ReconCli, KernelFromFramesIsTheSpeckleSuggestionAndAHandSetWidthWins) {
  const fs::path js = dir() / "kff_speckle.json";
  Result r = run("evaluate speckle " + seq() + " --plus-config " + xml() + " -c " + toml() + " --json " + js.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto k = readJson(js)["suggested_kernel_mm"];
  ASSERT_TRUE(k.is_array()) << r.out;

  const fs::path derived = dir() / "kff_derived.mha", byHand = dir() / "kff_by_hand.mha";
  const std::string common = "reconstruct " + seq() + " --plus-config " + xml() + " -c " + toml() +
                             " --type float32 --set grid.spacing=[2,2,2]";
  const fs::path used = dir() / "kff_used.toml";
  r = run(common + " --set recon.kernel_from_frames=true -o " + derived.string() + " --write-settings " + used.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const char* keys[] = {"recon.kernel_lateral_mm", "recon.kernel_axial_mm", "recon.kernel_elevation_mm"};
  for (int a = 0; a < 3; ++a)
    EXPECT_NE(r.out.find(fmt::format("{:<26} {:.3f} mm, derived", keys[a], k[a].get<double>())), std::string::npos)
        << r.out;
  std::string set;
  for (int a = 0; a < 3; ++a) set += fmt::format(" --set {}={:.17g}", keys[a], k[a].get<double>());
  r = run(common + set + " -o " + byHand.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const pp5::Volume dv = pp5::readVolume(derived.string()), hv = pp5::readVolume(byHand.string());
  ASSERT_EQ(dv.grid.dims, hv.grid.dims);
  std::size_t differ = 0, nonzero = 0;
  for (std::size_t i = 0; i < dv.grid.voxelCount(); ++i) {
    differ += dv.value(i) != hv.value(i) ? 1 : 0;
    nonzero += dv.value(i) != 0.0 ? 1 : 0;
  }
  EXPECT_EQ(differ, 0u);
  EXPECT_GT(nonzero, 0u);
  // The settings it wrote give the same volume again, the derived kernel now set in them.
  const fs::path again = dir() / "kff_again.mha";
  r = run("reconstruct " + seq() + " --plus-config " + xml() + " -c " + used.string() + " --type float32 -o " +
          again.string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find(fmt::format("recon.kernel_lateral_mm    {:.3f} mm, as set", k[0].get<double>())),
            std::string::npos)
      << r.out;
  const pp5::Volume av = pp5::readVolume(again.string());
  ASSERT_EQ(av.grid.dims, dv.grid.dims);
  std::size_t differAgain = 0;
  for (std::size_t i = 0; i < av.grid.voxelCount(); ++i) differAgain += av.value(i) != dv.value(i) ? 1 : 0;
  EXPECT_EQ(differAgain, 0u);
  // The default kernel gives another volume: the comparison above can fail.
  const fs::path fixed = dir() / "kff_fixed.mha";
  r = run(common + " -o " + fixed.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const pp5::Volume fv = pp5::readVolume(fixed.string());
  std::size_t differFixed = 0;
  for (std::size_t i = 0; i < fv.grid.voxelCount(); ++i) differFixed += fv.value(i) != dv.value(i) ? 1 : 0;
  EXPECT_GT(differFixed, 0u);

  // By hand wins, even at the default's value; the others are still derived.
  r = run(common + " --set recon.kernel_from_frames=true --set recon.kernel_axial_mm=1.0 -o " + derived.string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find(fmt::format("recon.kernel_axial_mm      1.000 mm, as set (derived: {:.3f})", k[1].get<double>())),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find(fmt::format("recon.kernel_lateral_mm    {:.3f} mm, derived", k[0].get<double>())),
            std::string::npos)
      << r.out;

  // A leave-out derives it from the kept frames alone: every second frame of
  // a real recording (the small sweep's frames, 4 mm apart, show no speckle
  // to measure), about twice as far apart as all of them.
  const std::string l14 = std::string(PP5_DATA_DIR) + "/BoneUltrasound_L14.igs.mha --plus-config " +
                          std::string(PP5_DATA_DIR) + "/BoneUltrasound_L14_config.xml";
  const fs::path l14js = dir() / "kff_l14.json";
  r = run("evaluate speckle " + l14 + " --json " + l14js.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const double allApart = readJson(l14js)["frame_spacing_mm"].get<double>();
  const fs::path loJs = dir() / "kff_leave_out.json";
  r = run("evaluate leave-out " + l14 + " --set grid.spacing=[0.5,0.5,0.5] --keep-every 2 --set recon.kernel_from_frames=true"
          " --json " + loJs.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto lo = readJson(loJs);
  EXPECT_TRUE(lo["kernel_from_frames"].get<bool>());
  const auto at = r.out.find("mm apart (median)");
  ASSERT_NE(at, std::string::npos) << r.out;
  const double apart = std::stod(r.out.substr(r.out.rfind("frames ", at) + 7));
  EXPECT_GT(apart, 1.6 * allApart) << r.out;
  EXPECT_LT(apart, 2.4 * allApart) << r.out;
  const auto el = r.out.find("recon.kernel_elevation_mm  ");
  ASSERT_NE(el, std::string::npos) << r.out;
  EXPECT_NEAR(std::stod(r.out.substr(el + 27)), 1.5 * apart, 0.002) << r.out;
  EXPECT_NEAR(lo["kernel_mm"][2].get<double>(), 1.5 * apart, 0.002) << r.out;  // the kernel it used
  EXPECT_NE(r.out.find("RMSE"), std::string::npos) << r.out;

  // Refused where it cannot apply, before any work.
  r = run("reconstruct " + seq() + " --plus-config " + xml() + " -o " + derived.string() + " --write-settings " +
          used.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("--write-settings writes TOML settings"), std::string::npos) << r.out;
  r = run(common + " --set recon.kernel_from_frames=true --set recon.method=trilinear -o " + derived.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("recon.kernel_from_frames derives the tent kernel"), std::string::npos) << r.out;
  // A probe held still: no reach along the sweep to derive.
  std::vector<pp5::Frame> still = pp5::readAllFrames(seq());
  for (auto& f : still) f.transforms = still.front().transforms;
  const fs::path stillPath = dir() / "kff_still.igs.mha";
  pp5::writeAllFrames(stillPath.string(), still);
  r = run("reconstruct " + stillPath.string() + " --plus-config " + xml() + " -c " + toml() +
          " --set recon.kernel_from_frames=true -o " + derived.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("the probe hardly moved"), std::string::npos) << r.out;
  r = run("run " + toml() + " -o " + (dir() / "kff_run").string() +
          " --set run.simulate_live=true --set recon.kernel_from_frames=true");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("run.simulate_live = true streams them"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir() / "kff_run" / "summary.json"));
  // The simulator's cached sweep is a recording too: the same small sweep as the fixture's, the same kernel.
  r = run("run " + toml() + " --serial -o " + (dir() / "kff_run_sim").string() +
          " --set sim.sweep.max_frames=8 --set sim.probe.width_px=64 --set sim.probe.height_px=96"
          " --set run.orbit_frames=0 --set render.width=64 --set render.height=48 --set recon.kernel_from_frames=true");
  ASSERT_EQ(r.status, 0) << r.out;
  for (int a = 0; a < 3; ++a)
    EXPECT_NE(r.out.find(fmt::format("{:<26} {:.3f} mm, derived", keys[a], k[a].get<double>())), std::string::npos)
        << r.out;

  // `run` streaming the recording derives the same kernel first, and writes it to settings.toml.
  const fs::path runDir = dir() / "kff_run_sequence";
  r = run("run " + toml() + " --serial -o " + runDir.string() + " --set run.source=sequence --set run.sequence=\"" +
          seq() + "\" --set run.plus_config=\"" + xml() +
          "\" --set run.orbit_frames=0 --set render.width=64 --set render.height=48 --set recon.kernel_from_frames=true");
  ASSERT_EQ(r.status, 0) << r.out;
  for (int a = 0; a < 3; ++a)
    EXPECT_NE(r.out.find(fmt::format("{:<26} {:.3f} mm, derived", keys[a], k[a].get<double>())), std::string::npos)
        << r.out;
  r = run("config " + (runDir / "settings.toml").string());
  ASSERT_EQ(r.status, 0) << r.out;
  for (int a = 0; a < 3; ++a) {
    const std::string key = std::string(keys[a]).substr(6) + " = ";  // "kernel_lateral_mm = "
    const auto at = r.out.find("\n" + key);
    ASSERT_NE(at, std::string::npos) << r.out;
    EXPECT_NEAR(std::stod(r.out.substr(at + 1 + key.size())), k[a].get<double>(), 1e-12) << key;
  }
}

// `run` measures the kernel over the frames its constant-interval capture
// takes, judged as the host judges them, after the crop: one pair fewer than
// the frames the pipeline then takes (every pair of BoneUltrasound_L14 shows
// speckle). Without the crop the capture takes another number of frames.
TEST_F(ReconCli, RunDerivesTheKernelFromTheFramesItsCaptureTakes) {
  const std::string common = "run " + std::string(PP5_SOURCE_DIR) + "/tests/configs/mpi_small.toml --serial"
                             " --set run.source=sequence --set run.sequence=\"" + std::string(PP5_DATA_DIR) +
                             "/BoneUltrasound_L14.igs.mha\" --set run.plus_config=\"" + std::string(PP5_DATA_DIR) +
                             "/BoneUltrasound_L14_config.xml\" --set recon.kernel_from_frames=true"
                             " --set run.capture_interval_mm=1.0";
  auto counts = [](const std::string& out) {
    const auto p = out.find(" pairs, pixel");
    const auto f = out.find(" frames through the serial pipeline");
    EXPECT_NE(p, std::string::npos) << out;
    EXPECT_NE(f, std::string::npos) << out;
    if (p == std::string::npos || f == std::string::npos) return std::pair<int, int>{-1, -1};
    return std::pair<int, int>{std::stoi(out.substr(out.rfind('(', p) + 1)), std::stoi(out.substr(out.rfind(": ", f) + 2))};
  };
  Result r = run(common + " -o " + (dir() / "kff_capture_crop").string() +
                 " --set run.crop_origin=[0,0] --set run.crop_size=[200,100]");
  ASSERT_EQ(r.status, 0) << r.out;
  const auto [pairsCrop, framesCrop] = counts(r.out);
  EXPECT_EQ(pairsCrop + 1, framesCrop) << r.out;
  EXPECT_LT(framesCrop, 21) << r.out;  // the capture left some out
  r = run(common + " -o " + (dir() / "kff_capture").string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto [pairs, frames] = counts(r.out);
  EXPECT_EQ(pairs + 1, frames) << r.out;
  EXPECT_NE(frames, framesCrop) << r.out;

  // Subsampled by 4, the pixels the pipeline is given are 4 times the recording's: L14's axial cell
  // (under one of them) makes an axial half-width of twice that pixel, not twice the recording's.
  auto derived = [](const std::string& out, const std::string& key) {
    const auto at = out.find(fmt::format("{:<26} ", key));
    EXPECT_NE(at, std::string::npos) << out;
    return at == std::string::npos ? -1.0 : std::stod(out.substr(at + 27));
  };
  const double axial = derived(r.out, "recon.kernel_axial_mm");
  const double lateral = derived(r.out, "recon.kernel_lateral_mm");
  const auto px = r.out.find("pixel ");
  ASSERT_NE(px, std::string::npos) << r.out;
  const double pixelY = std::stod(r.out.substr(r.out.find(" x ", px) + 3));
  EXPECT_LT(axial, 2.0 * 4.0 * pixelY * 0.9) << r.out;  // the cell, not the subsampled pixel, without subsampling
  r = run(common + " -o " + (dir() / "kff_capture_sub").string() + " --set run.subsample=4");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("the reconstruction is given pixels of"), std::string::npos) << r.out;
  EXPECT_NEAR(derived(r.out, "recon.kernel_axial_mm"), 2.0 * 4.0 * pixelY, 2e-3) << r.out;
  EXPECT_NEAR(derived(r.out, "recon.kernel_lateral_mm"), lateral, 1e-3) << r.out;  // its cell spans 4 pixels or more
}

// `evaluate leave-out` takes [grid] as `reconstruct` does (it used PLUS's rule
// whatever [grid] said): a fixed grid is the grid it reconstructs on.
TEST_F(ReconCli, LeaveOutUsesTheGridItIsGiven) {
  const fs::path js = dir() / "lo_grid.json";
  Result r = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
                 " --keep-every 2 --set grid.auto_extent=false --set grid.dims=[12,54,102]"
                 " --set grid.origin=[-100,-52,-16] --set grid.spacing=[2,2,2] --json " + js.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto j = readJson(js);
  EXPECT_EQ(j["grid"]["dims"][0].get<int>(), 12);
  EXPECT_EQ(j["grid"]["dims"][2].get<int>(), 102);
  EXPECT_DOUBLE_EQ(j["grid"]["origin_mm"][1].get<double>(), -52.0);
  EXPECT_NE(r.out.find("12x54x102 voxels of 2 x 2 x 2 mm"), std::string::npos) << r.out;
  // With an automatic extent, the grid `reconstruct` fits with the same settings (the sweep's own
  // config gives an extent too, which TOML settings replace, as they do for `reconstruct`).
  const fs::path autoJs = dir() / "lo_grid_auto.json";
  r = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
          " --keep-every 2 --set grid.spacing=[2,2,2] --json " + autoJs.string());
  ASSERT_EQ(r.status, 0) << r.out;
  const auto a = readJson(autoJs)["grid"]["dims"];
  r = run("reconstruct " + seq() + " --plus-config " + xml() + " -c " + toml() + " --set grid.spacing=[2,2,2] -o " +
          (dir() / "lo_grid_auto.mha").string());
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find(fmt::format("grid {}x{}x{}, spacing 2 2 2 mm", a[0].get<int>(), a[1].get<int>(), a[2].get<int>())),
            std::string::npos)
      << r.out;
  // The same grid far from the sweep: nothing of it holds a value, and the command says so.
  r = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
          " --keep-every 2 --set grid.auto_extent=false --set grid.dims=[12,54,102]"
          " --set grid.origin=[5000,0,0] --set grid.spacing=[2,2,2]");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("nothing to compare"), std::string::npos) << r.out;
}

TEST_F(ReconCli, EvaluateRefusesToScoreNothing) {
  const pp5::Volume truth = pp5::readVolume((dir() / "doll_truth.mha").string());
  pp5::Volume far = truth;
  far.grid.origin += pp5::Vec3(10000.0, 0.0, 0.0);
  const fs::path farPath = dir() / "far_truth.mha";
  pp5::writeVolume(farPath.string(), far);
  Result r = run("evaluate truth " + seq() + " --plus-config " + xml() + " -c " + toml() + " --truth " +
                 farPath.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("nothing to compare"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("PSNR"), std::string::npos) << r.out;

  pp5::Volume nan = truth.as(pp5::ScalarType::F32);
  nan.setValue(nan.grid.voxelCount() / 2, std::nan(""));
  const fs::path nanPath = dir() / "nan_truth.mha";
  pp5::writeVolume(nanPath.string(), nan);
  r = run("evaluate truth " + seq() + " --plus-config " + xml() + " -c " + toml() + " --truth " + nanPath.string());
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("1 voxels that are not finite"), std::string::npos) << r.out;

  // One frame kept of eight, nearest neighbour: no held-out pixel has all 8 voxels around it.
  r = run("evaluate leave-out " + seq() + " --plus-config " + xml() + " -c " + toml() +
          " --keep-every 8 --set recon.method=nearest --set recon.fill_holes=false");
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_NE(r.out.find("nothing to compare"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("RMSE"), std::string::npos) << r.out;
}

// The accuracy target of docs/quality.md on a 40 mm section of the default
// doll sweep (ideal medium, full-size frames, 1 mm grid): the paper's method
// (tent + fill-in, the doll's kernel) against nearest neighbour with hole
// filling, both measured against the expected image by `evaluate truth`.
// The whole 2 mm sweep gives 0.723 (docs/quality.md); this section 0.73.
TEST(ReconAccuracy, PaperMethodIsWithinPointEightOfNearestWithHoleFillingOnTheDoll) {
  const fs::path d = fs::temp_directory_path() / ("pp5cli-accuracy-" + std::to_string(::getpid()));
  fs::remove_all(d);
  const std::string toml = std::string(PP5_SOURCE_DIR) + "/configs/doll.toml";
  const Result s = run("simulate " + toml + " -o " + d.string() +
                       " --set sim.bmode.medium=ideal --set sim.sweep.length_mm=40 --set output.preview_frames=0");
  ASSERT_EQ(s.status, 0) << s.out;
  auto rmse = [&](const std::string& method, const std::string& name) {
    const fs::path js = d / (name + ".json");
    const Result r = run("evaluate truth " + (d / "doll_sweep.igs.mha").string() + " --plus-config " +
                         (d / "doll_config.xml").string() + " -c " + toml + " --truth " +
                         (d / "doll_expected.mha").string() + " " + method + " --json " + js.string());
    EXPECT_EQ(r.status, 0) << r.out;
    const auto j = readJson(js);
    EXPECT_EQ(j["hole_fraction"].get<double>(), 0.0) << name;
    return std::array<double, 2>{j["rmse"].get<double>(), j["rmse_tissue"].get<double>()};
  };
  const auto paper = rmse("--set recon.method=tent --set recon.fill_in=true", "paper");
  const auto nearest = rmse("--set recon.method=nearest --set recon.fill_holes=true", "nearest");
  RecordProperty("ratio_all", std::to_string(paper[0] / nearest[0]));
  RecordProperty("ratio_tissue", std::to_string(paper[1] / nearest[1]));
  EXPECT_LE(paper[0], 0.8 * nearest[0]) << paper[0] << " against " << nearest[0];
  EXPECT_LT(paper[1], nearest[1]) << "and in tissue too";
  fs::remove_all(d);
}

}  // namespace
