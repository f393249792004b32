#include "sim/sim_settings.hpp"
#include "core/threads.hpp"

#include <limits>

#include "core/config.hpp"

namespace pp5::sim {

namespace {

void registerProbe(ConfigSchema& c, ProbeSettings& p) {
  c.section("sim.probe", "The simulated 2D scanner's probe.");
  enumOption(c, "sim.probe.preset", &p.preset, ProbePreset::Paper35,
           "`paper35`: the 1990 paper's 3.5 MHz linear probe, 98 x 195 mm field, 256 x 405 pixels; "
           "`linear75`: a modern 7.5 MHz linear probe, 38 x 50 mm field, 256 x 336 pixels.");
  c.option("sim.probe.width_px", &p.widthPx, 0, 0, 4096,
           "Frame width in pixels (lateral); 0 keeps the preset's. The field width stays the preset's.");
  c.option("sim.probe.height_px", &p.heightPx, 0, 0, 4096, "Frame height in pixels (depth); 0 keeps the preset's.");
  c.option("sim.probe.depth_mm", &p.depthMm, 0.0, 0.0, 400.0, "Imaging depth in mm; 0 keeps the preset's.");
}

void registerBMode(ConfigSchema& c, BModeSettings& b) {
  c.section("sim.bmode", "The B-mode image model: speckle by convolution, interfaces, attenuation, display.");
  c.option("sim.bmode.dynamic_range_db", &b.dynamicRangeDb, 60.0, 10.0, 120.0,
           "Log-compression range in dB mapped onto pixel values 0..255.");
  c.option("sim.bmode.gain_db", &b.gainDb, 0.0, -60.0, 60.0, "Overall receive gain in dB.");
  c.option("sim.bmode.tgc_db_per_cm_mhz", &b.tgcDbPerCmMHz, -1.0, -1.0, 5.0,
           "Time-gain compensation slope (one way, dB/cm/MHz), applied over the depths the phantom's tissue "
           "spans; -1 uses the phantom's own (water for the doll and the wires, soft tissue for the forearm).");
  c.option("sim.bmode.noise_db", &b.noiseDb, -58.0, -200.0, 0.0,
           "Electronic noise (RMS amplitude) in dB relative to white, added after the TGC.");
  c.option("sim.bmode.scatterers_per_cell", &b.scatterersPerCell, 16.0, 1.0, 200.0,
           "Scatterers per resolution cell (the PSF's FWHM volume at focus); sets the scatterer lattice pitch. "
           "About 10 or more give fully developed speckle.");
  c.option("sim.bmode.specular_width_deg", &b.specularWidthDeg, 12.0, 1.0, 90.0,
           "Angular width (Gaussian sigma, degrees) over which a smooth interface still echoes back "
           "to the probe as the beam leaves its normal.");
  enumOption(c, "sim.bmode.medium", &b.medium, Medium::Physical,
           "`physical`: attenuation, specular interface echoes, bone rims, transmission loss and shadows, "
           "compensated by the TGC; `ideal`: speckle from each tissue's backscatter only (no attenuation, TGC, "
           "interfaces or shadows), for which `pp5echo simulate`'s expected image (`<phantom>_expected.mha`) is "
           "exact. Accuracy studies (`pp5echo evaluate truth`) use `ideal` to measure the reconstruction rather "
           "than the physics.");
}

void registerSweep(ConfigSchema& c, SweepSettings& s) {
  c.section("sim.sweep", "How the probe sweeps over the phantom and when frames are captured.");
  enumOption(c, "sim.sweep.kind", &s.kind, SweepKind::Parallel,
           "`parallel`: straight passes along the phantom's x axis (side by side when `passes` > 1); "
           "`angled`: one pass at `angle_deg`; `back_and_forth`: `repeats` passes forth and back over "
           "the same line; `freehand`: a 6-DOF hand-held path with drift, tilt, roll and tremor.");
  enumOption(c, "sim.sweep.capture", &s.capture, Capture::Interval,
           "`interval`: digitise a frame once the image has moved `capture_interval_mm` since the last "
           "one, measured on the reported pose (as the 1990 system did); `every_frame`: every video frame.");
  c.option("sim.sweep.capture_interval_mm", &s.captureIntervalMm, 2.0, 0.1, 100.0,
           "Distance between captured frames (largest displacement of the image's corners), mm.");
  c.option("sim.sweep.speed_mm_s", &s.speedMmPerS, 6.0, 0.1, 500.0, "Mean probe speed along a pass, mm/s.");
  c.option("sim.sweep.length_mm", &s.lengthMm, 0.0, 0.0, 2000.0,
           "Length of one pass in mm; 0 uses the phantom's (doll 190, forearm 150, wires 100).");
  c.option("sim.sweep.frame_rate_hz", &s.frameRateHz, 30.0, 1.0, 1000.0, "Video frame rate of the scanner.");
  c.option("sim.sweep.passes", &s.passes, 1, 1, 100, "Side-by-side passes of a `parallel` sweep.");
  c.option("sim.sweep.pass_spacing_mm", &s.passSpacingMm, 20.0, 0.0, 500.0,
           "Lateral distance between the passes of a `parallel` sweep, mm.");
  c.option("sim.sweep.angle_deg", &s.angleDeg, 0.0, -90.0, 90.0,
           "Direction of an `angled` sweep, degrees from the phantom's x axis; the image plane turns with it.");
  c.option("sim.sweep.repeats", &s.repeats, 3, 1, 100, "One-way passes of a `back_and_forth` sweep.");
  c.option("sim.sweep.lateral_offset_mm", &s.lateralOffsetMm, 0.0, -500.0, 500.0,
           "Shifts the sweep sideways (across its direction), mm.");
  c.option("sim.sweep.max_frames", &s.maxFrames, 0, 0, 1000000, "Stop after this many captured frames; 0 = no limit.");
}

void registerArm(ConfigSchema& c, ArmSettings& a) {
  c.section("sim.arm",
            "The 1990 system's 3-DOF arm: x, y and theta read through potentiometers and a 12-bit A/D converter.");
  c.option("sim.arm.sample_rate_hz", &a.sampleRateHz, 800.0, 10.0, 100000.0, "A/D sampling rate of the arm.");
  c.option("sim.arm.noise_counts", &a.noiseCounts, 0.5, 0.0, 100.0,
           "Gaussian noise on each A/D reading, in counts (standard deviation).");
  c.option("sim.arm.x_span_mm", &a.xSpanMm, 400.0, 10.0, 5000.0, "x travel covered by counts 0..4095, mm.");
  c.option("sim.arm.y_span_mm", &a.ySpanMm, 300.0, 10.0, 5000.0, "y travel covered by counts 0..4095, mm.");
  c.option("sim.arm.theta_span_deg", &a.thetaSpanDeg, 180.0, 1.0, 360.0,
           "Rotation covered by counts 0..4095, degrees, centred on 0.");
  c.option("sim.arm.reference_to_tracker_mm", &a.referenceToTrackerMm, {200.0, 150.0, 0.0}, -10000.0, 10000.0,
           "Where the phantom's Reference origin lies in the arm's (Tracker) frame, mm; recorded as "
           "ReferenceToTracker.");
}

void registerFreehand(ConfigSchema& c, FreehandSettings& f) {
  c.section("sim.freehand", "The 6-DOF hand-held sweep (`sim.sweep.kind = \"freehand\"`) and its tracker.");
  c.option("sim.freehand.drift_mm", &f.driftMm, 3.0, 0.0, 100.0, "Slow sideways wander of the hand, mm (peak).");
  c.option("sim.freehand.heave_mm", &f.heaveMm, 1.0, 0.0, 50.0, "Slow up-and-down wander, mm (peak).");
  c.option("sim.freehand.tilt_deg", &f.tiltDeg, 5.0, 0.0, 45.0,
           "Fanning of the image plane about the probe's lateral axis, degrees (peak).");
  c.option("sim.freehand.roll_deg", &f.rollDeg, 3.0, 0.0, 45.0,
           "Rocking within the image plane (about the elevation axis), degrees (peak).");
  c.option("sim.freehand.yaw_deg", &f.yawDeg, 3.0, 0.0, 45.0, "Turning about the vertical axis, degrees (peak).");
  c.option("sim.freehand.tremor_mm", &f.tremorMm, 0.15, 0.0, 5.0, "Physiological tremor (8-12 Hz), mm (peak).");
  c.option("sim.freehand.tremor_deg", &f.tremorDeg, 0.2, 0.0, 5.0, "Tremor in rotation, degrees (peak).");
  c.option("sim.freehand.tracker_noise_mm", &f.trackerNoiseMm, 0.1, 0.0, 10.0,
           "Tracker position noise per reading, mm (standard deviation).");
  c.option("sim.freehand.tracker_noise_deg", &f.trackerNoiseDeg, 0.05, 0.0, 10.0,
           "Tracker rotation noise per reading, degrees (standard deviation).");
}

}  // namespace

void registerOptions(ConfigSchema& c, SimSettings& s) {
  c.section("sim", "The simulated world: phantom, scanner and probe motion (`pp5echo simulate`).");
  c.option("sim.seed", &s.seed, std::uint64_t{1}, std::uint64_t{0},
           static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max()),
           "Seed of every random choice (scatterers, noise, hand motion); the same seed gives the same data.");
  enumOption(c, "sim.phantom", &s.phantom, PhantomKind::Doll,
           "`doll`: the 1990 paper's 16.5 cm plastic baby doll hung in a water tank; `forearm`: skin, fat, "
           "muscle with fascia, radius and ulna; `wires`: an N-wire calibration phantom with spheres of known size.");
  enumOption(c, "sim.truth_type", &s.truthType, TruthType::Float32,
           "Voxel type of the ground-truth echogenicity volume.");
  c.option("sim.threads", &s.threads, 0, 0, kMaxThreads,
           "Threads simulating frames in parallel; 0 = every core. The frames do not depend on it.");
  registerProbe(c, s.probe);
  registerBMode(c, s.bmode);
  registerSweep(c, s.sweep);
  registerArm(c, s.arm);
  registerFreehand(c, s.freehand);
}

}  // namespace pp5::sim
