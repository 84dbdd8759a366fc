# octolod-bench's `meshlab-qec` peer: MeshLab's quadric edge collapse
# (pymeshlab), run by `octolod-bench run-one --method meshlab-qec` as
#   PYTHON -c "$(this file)" INPUT OUTPUT TARGET
# Loads INPUT, decimates to TARGET faces with MeshLab's defaults (optimal
# placement, quality threshold 0.3, no boundary or normal preservation,
# auto-clean), writes OUTPUT (binary PLY, positions only) and prints one
# JSON line: input_triangles, load_seconds, seconds (the filter alone),
# triangles, vertices, filter (the call as made).
import json
import sys
import time

import pymeshlab

inp, out, target = sys.argv[1], sys.argv[2], int(sys.argv[3])
t = time.perf_counter()
ms = pymeshlab.MeshSet()
ms.load_new_mesh(inp)
load = time.perf_counter() - t
n_in = ms.current_mesh().face_number()
params = dict(targetfacenum=target, optimalplacement=True, qualitythr=0.3, preserveboundary=False, preservenormal=False, preservetopology=False, planarquadric=False, autoclean=True)
t = time.perf_counter()
ms.meshing_decimation_quadric_edge_collapse(**params)
seconds = time.perf_counter() - t
m = ms.current_mesh()
ms.save_current_mesh(out, binary=True, save_vertex_normal=False, save_vertex_color=False, save_vertex_quality=False, save_face_quality=False, save_face_color=False)
call = "meshing_decimation_quadric_edge_collapse(" + ", ".join(f"{k}={v}" for k, v in params.items()) + ")"
print(json.dumps(dict(input_triangles=n_in, load_seconds=load, seconds=seconds, triangles=m.face_number(), vertices=m.vertex_number(), filter=call)))
