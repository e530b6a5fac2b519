#!/usr/bin/env python3
"""Times VTK's vtkFixedPointVolumeRayCastMapper on volwarp scenes (see README.md).

    python vtk_bench.py SCENES.json          # one JSON object per scene on stdout

SCENES.json is a list of scenes as `cargo bench -p volwarp-server --bench vs_vtk` writes them:
the raw volume (path, dims, voxel type, spacing), the transfer function as a table over the
data range (x in data units, r, g, b, a with a the opacity of one `opacity_unit` of thickness),
the camera (eye, target, up, vertical field of view), the viewport, the sample distance in world
units, the threads and the number of timed renders. Each output line is JSON with the median,
minimum and every wall time of `renWin.Render()` and of the mapper's own `GetTimeToDraw()`.
"""
import json
import os
import statistics
import sys
import time

import numpy as np
import vtk
from vtk.util import numpy_support

TYPES = {
    "uint8": (np.uint8, vtk.VTK_UNSIGNED_CHAR),
    "int8": (np.int8, vtk.VTK_SIGNED_CHAR),
    "uint16": (np.uint16, vtk.VTK_UNSIGNED_SHORT),
    "int16": (np.int16, vtk.VTK_SHORT),
    "float32": (np.float32, vtk.VTK_FLOAT),
}


def image_data(scene):
    dtype, _ = TYPES[scene["voxel_type"]]
    nx, ny, nz = scene["dims"]
    values = np.fromfile(scene["volume"], dtype=np.dtype(dtype).newbyteorder("<"))
    if values.size != nx * ny * nz:
        raise SystemExit(f"{scene['volume']}: {values.size} voxels, expected {nx * ny * nz}")
    img = vtk.vtkImageData()
    img.SetDimensions(nx, ny, nz)
    sx, sy, sz = scene["spacing"]
    img.SetSpacing(sx, sy, sz)
    # volwarp puts voxel centres at (i + 0.5) * spacing: the same box [0, dims * spacing].
    img.SetOrigin(0.5 * sx, 0.5 * sy, 0.5 * sz)
    arr = numpy_support.numpy_to_vtk(values.astype(dtype, copy=False), deep=True)
    arr.SetName("scalars")
    img.GetPointData().SetScalars(arr)
    return img


def volume_property(scene):
    color = vtk.vtkColorTransferFunction()
    opacity = vtk.vtkPiecewiseFunction()
    for x, r, g, b, a in scene["tf"]:
        color.AddRGBPoint(x, r, g, b)
        opacity.AddPoint(x, a)
    prop = vtk.vtkVolumeProperty()
    prop.SetColor(color)
    prop.SetScalarOpacity(opacity)
    prop.SetInterpolationTypeToLinear()
    if scene.get("shade"):
        # volwarp's Shading::DEFAULT (the light differs: VTK's is the renderer's headlight).
        prop.ShadeOn()
        prop.SetAmbient(0.3)
        prop.SetDiffuse(0.7)
        prop.SetSpecular(0.2)
        prop.SetSpecularPower(32.0)
    else:
        prop.ShadeOff()
    prop.SetScalarOpacityUnitDistance(scene["opacity_unit"])
    return prop


def run(scene):
    mapper = vtk.vtkFixedPointVolumeRayCastMapper()
    mapper.SetInputData(image_data(scene))
    mapper.SetAutoAdjustSampleDistances(0)
    mapper.SetLockSampleDistanceToInputSpacing(0)
    mapper.SetSampleDistance(scene["sample_distance"])
    mapper.SetImageSampleDistance(1.0)
    mapper.SetNumberOfThreads(scene["threads"])
    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(volume_property(scene))

    ren = vtk.vtkRenderer()
    ren.SetBackground(0, 0, 0)
    ren.AddVolume(volume)
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(0)
    win.AddRenderer(ren)
    w, h = scene["width"], scene["height"]
    win.SetSize(w, h)
    cam = ren.GetActiveCamera()
    cam.SetPosition(*scene["eye"])
    cam.SetFocalPoint(*scene["target"])
    cam.SetViewUp(*scene["up"])
    cam.SetViewAngle(scene["fov_y_deg"])
    ren.ResetCameraClippingRange()

    win.Render()  # warm-up: builds the mapper's tables and min-max volume
    walls, draws = [], []
    for _ in range(scene["runs"]):
        volume.Modified()
        t0 = time.perf_counter()
        win.Render()
        walls.append((time.perf_counter() - t0) * 1e3)
        draws.append(mapper.GetTimeToDraw() * 1e3)
    if scene.get("png"):
        grab = vtk.vtkWindowToImageFilter()
        grab.SetInput(win)
        grab.Update()
        out = vtk.vtkPNGWriter()
        out.SetFileName(scene["png"])
        out.SetInputConnection(grab.GetOutputPort())
        out.Write()
    return {
        "name": scene["name"],
        "width": w,
        "height": h,
        "threads": scene["threads"],
        "wall_ms_median": statistics.median(walls),
        "wall_ms_min": min(walls),
        "draw_ms_median": statistics.median(draws),
        "wall_ms": walls,
        "render_window": win.GetClassName(),
        "vtk": vtk.vtkVersion.GetVTKVersion(),
    }


def main():
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    with open(sys.argv[1]) as f:
        scenes = json.load(f)
    for scene in scenes:
        print(json.dumps(run(scene)), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    main()
