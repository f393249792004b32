#!/usr/bin/python3
"""Times VTK's CPU ray-cast volume mapper on a pp5echo volume, for docs/benchmarks.md.

Renders VOLUME (.mha, as `pp5echo run` writes it) at the same image size, camera, sample step,
transfer functions and Phong terms as the pp5echo run whose settings.toml is given, with
vtkFixedPointVolumeRayCastMapper (VTK's multi-threaded CPU ray caster), offscreen. Each timed
render follows a small camera turn, so nothing is cached between renders; the median of N is
printed, and the last image is written as a PNG for a visual comparison.

Needs Debian's python3-vtk9 and an X server; run it under xvfb-run with the system Python:

    xvfb-run -a /usr/bin/python3 scripts/vtk_compare.py out/doll/volume.mha out/doll/settings.toml \
        --threads 2 --renders 7 --png out/doll/vtk_over.png
"""
import argparse
import math
import statistics
import sys
import time
import tomllib

import vtk


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("volume")
    ap.add_argument("settings", help="settings.toml written by the pp5echo run")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--renders", type=int, default=7)
    ap.add_argument("--png", default="")
    a = ap.parse_args()

    with open(a.settings, "rb") as f:
        cfg = tomllib.load(f)
    r = cfg["render"]
    tf = r["tf"]
    sh = r.get("shading", {})

    reader = vtk.vtkMetaImageReader()
    reader.SetFileName(a.volume)
    reader.Update()
    img = reader.GetOutput()
    lo = [img.GetOrigin()[i] - 0.5 * img.GetSpacing()[i] for i in range(3)]
    hi = [img.GetOrigin()[i] + (img.GetDimensions()[i] - 0.5) * img.GetSpacing()[i] for i in range(3)]
    centre = [(lo[i] + hi[i]) / 2 for i in range(3)]
    radius = 0.5 * math.dist(lo, hi)

    opacity = vtk.vtkPiecewiseFunction()
    for p in tf["opacity"]:
        opacity.AddPoint(p[0], p[1])
    colour = vtk.vtkColorTransferFunction()
    for p in tf["colour"]:
        colour.AddRGBPoint(p[0], p[1], p[2], p[3])
    prop = vtk.vtkVolumeProperty()
    prop.SetScalarOpacity(opacity)
    prop.SetColor(colour)
    prop.SetInterpolationTypeToLinear()
    prop.SetScalarOpacityUnitDistance(r["opacity_unit_mm"])
    if sh.get("mode", "phong") == "phong":
        prop.ShadeOn()
        prop.SetAmbient(sh.get("ambient", 0.25))
        prop.SetDiffuse(sh.get("diffuse", 0.7))
        prop.SetSpecular(sh.get("specular", 0.3))
        prop.SetSpecularPower(sh.get("shininess", 24.0))

    mapper = vtk.vtkFixedPointVolumeRayCastMapper()
    mapper.SetInputConnection(reader.GetOutputPort())
    step = r["step_mm"] if r["step_mm"] > 0 else 0.5 * min(img.GetSpacing())
    mapper.SetSampleDistance(step)
    mapper.SetInteractiveSampleDistance(step)
    mapper.AutoAdjustSampleDistancesOff()
    mapper.SetNumberOfThreads(a.threads)
    mode = r["compositing"][0]
    if mode == "mip":
        mapper.SetBlendModeToMaximumIntensity()
    elif mode == "additive":
        mapper.SetBlendModeToAdditive()
    else:
        mapper.SetBlendModeToComposite()

    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)
    ren = vtk.vtkRenderer()
    ren.AddVolume(volume)
    ren.SetBackground(0, 0, 0)
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.AddRenderer(ren)
    win.SetSize(r["width"], r["height"])

    az, el = math.radians(r["azimuth_deg"]), math.radians(r["elevation_deg"])
    d = [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
    cam = ren.GetActiveCamera()
    cam.SetFocalPoint(*centre)
    cam.SetPosition(*[centre[i] + d[i] * radius * r["distance"] for i in range(3)])
    cam.SetViewUp(0, 0, 1)
    cam.SetViewAngle(r["fov_deg"])
    if r["projection"] == "orthographic":
        cam.ParallelProjectionOn()
        cam.SetParallelScale(radius)
    ren.ResetCameraClippingRange()

    win.Render()  # warm-up: builds the mapper's tables
    times = []
    for i in range(a.renders):
        cam.Azimuth(0.5 if i % 2 == 0 else -0.5)
        ren.ResetCameraClippingRange()
        t = time.perf_counter()
        win.Render()
        times.append((time.perf_counter() - t) * 1000.0)
    print("vtkFixedPointVolumeRayCastMapper %dx%d, %s, %d threads: median %.1f ms over %d renders (min %.1f, max %.1f)"
          % (r["width"], r["height"], mode, a.threads, statistics.median(times), len(times), min(times), max(times)))
    if a.png:
        w2i = vtk.vtkWindowToImageFilter()
        w2i.SetInput(win)
        w2i.Update()
        wr = vtk.vtkPNGWriter()
        wr.SetFileName(a.png)
        wr.SetInputConnection(w2i.GetOutputPort())
        wr.Write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
