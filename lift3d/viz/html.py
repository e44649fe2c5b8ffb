"""``lift3d plot FILE.ply --html OUT.html``: one self-contained web page showing labelled points or a mesh.

The page embeds the geometry (base64 float32 positions, uint8 colours, uint32 triangles) and a small WebGL
viewer written for it (about 200 lines of JavaScript, no library): drag to orbit, wheel to zoom, buttons or
the keys ``i`` / ``c`` switch between instance and class colours (``page.html#classes`` opens in class
colours), and a legend lists the classes present
with their colours and point counts. Nothing is fetched when it is opened (no network, no server), so it can
be mailed or attached to an issue and opened in any browser with WebGL.

Colours are the palette of the PNG pictures (:mod:`lift3d.viz.palette`): an instance id has the same
colour everywhere; stuff is drawn in grey-ish tints of its class colour in the instance view.

PyVista's ``export_html`` was considered and not used: it needs five more packages (trame, trame-vtk,
trame-vuetify, trame-pyvista, nest_asyncio2), starts a trame server to export, tried to reach
gitlab.kitware.com during the export, and writes 3.3 MB for 100 000 points (the vtk.js viewer alone is
about 2.5 MB), where this page is the data plus about 8 kB.

Examples
--------
>>> import numpy as np, tempfile, os
>>> out = os.path.join(tempfile.mkdtemp(), "view.html")
>>> write_html({"xyz": np.random.default_rng(0).random((50, 3)), "semantic": np.repeat([1, 2], 25),
...             "instance": np.repeat([0, 3], 25)}, out)
PosixPath('...view.html')
>>> text = open(out).read(); "<canvas" in text and "http" not in text.split("<script>")[1]
True
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from lift3d.data.categories import as_class_table
from lift3d.utils.atomic import write_text_atomic
from lift3d.utils.geometry import vertex_normals
from lift3d.viz.palette import INSTANCE_NONE, instance_color, semantic_color, stuff_tint
from lift3d.viz.points import _axis, _resolve_hidden, _with_files_beside, as_geometry

#: Points embedded at most (a random subset beyond; about 16 bytes of page per point).
MAX_POINTS = 400_000


def write_html(points_or_path: Any, path: str | Path, *, classes: Any = None, up: str = "z",
               max_points: int = MAX_POINTS, hide=(), point_size: float | None = None, title: str | None = None,
               seed: int = 0) -> Path:
    """Write the self-contained viewer page of labelled points or a mesh (atomically).

    Parameters
    ----------
    points_or_path
        What :func:`lift3d.viz.points.as_geometry` accepts (``points.ply``, ``mesh.ply``, arrays...).
    path : str or Path
        The ``.html`` to write.
    classes : optional
        Class table (default: ``classes.json`` beside the file).
    up : str
        The scene's up axis (``x y z -x -y -z``): the orbit turns about it.
    max_points : int
        A point cloud larger than this is subsampled (uniformly at random, ``seed``); meshes are kept whole.
    hide : sequence of str
        Class names or ids to leave out.
    point_size : float, optional
        Point size in pixels (default: from the number of points).
    title : str, optional
        Page title (default: the file name).

    Returns
    -------
    Path
    """
    geom = as_geometry(points_or_path)
    found, _ = _with_files_beside(geom, classes)
    table = as_class_table(found) if found is not None else []
    hidden = _resolve_hidden(hide, table)
    if hidden:
        geom = geom.subset(~np.isin(geom.semantic, list(hidden)))
    if not geom.is_mesh and len(geom.xyz) > max_points:
        keep = np.zeros(len(geom.xyz), bool)
        keep[np.random.default_rng(seed).choice(len(geom.xyz), max_points, replace=False)] = True
        geom = geom.subset(keep)
    sem_rgb = semantic_color(geom.semantic, table)
    inst_rgb = stuff_tint(sem_rgb) if geom.has_semantic else \
        np.tile(np.asarray(INSTANCE_NONE, np.uint8), (len(geom.xyz), 1))
    thing = geom.instance > 0
    inst_rgb[thing] = instance_color(geom.instance[thing])
    names = {c.id: c.name for c in table}
    ids, counts = np.unique(geom.semantic, return_counts=True)
    legend = [{"name": names.get(int(i), "void" if i <= 0 else f"class_{int(i)}"),
               "color": semantic_color(int(i), table)[0].tolist(), "count": int(n)} for i, n in zip(ids, counts)]
    xyz = np.asarray(geom.xyz, np.float64)
    lo, hi = (xyz.min(0), xyz.max(0)) if len(xyz) else (np.zeros(3), np.ones(3))
    center, radius = (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    data: dict[str, Any] = {
        "positions": _b64(((xyz - center) / radius).astype("<f4")),
        "instanceColors": _b64(inst_rgb.astype(np.uint8)), "classColors": _b64(sem_rgb.astype(np.uint8)),
        "count": int(len(xyz)), "up": _axis(up).tolist(), "legend": legend,
        "instances": int(len(np.unique(geom.instance[thing]))),
        "pointSize": float(point_size or np.clip(700.0 / np.sqrt(max(len(xyz), 1)), 1.5, 6.0)),
    }
    if geom.is_mesh:
        data["indices"] = _b64(np.asarray(geom.faces, "<u4"))
        data["normals"] = _b64(np.asarray(vertex_normals(xyz, geom.faces), "<f4"))
    name = title or (geom.source.name if geom.source is not None else "labelled geometry")
    page = _TEMPLATE.replace("__TITLE__", html.escape(f"lift3d · {name}")) \
        .replace("__DATA__", json.dumps(data, separators=(",", ":")))
    path = Path(path)
    write_text_atomic(path, page)
    return path


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


_TEMPLATE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
html,body{margin:0;height:100%;background:#fff;font:13px/1.35 system-ui,sans-serif;color:#222;overflow:hidden}
canvas{width:100%;height:100%;display:block;cursor:grab}
#panel{position:absolute;top:10px;right:10px;background:rgba(255,255,255,.92);border:1px solid #ccc;
 border-radius:6px;padding:8px 10px;max-height:90%;overflow:auto}
#panel h1{font-size:14px;margin:0 0 6px}
button{font:inherit;padding:2px 8px;margin-right:4px;border:1px solid #999;background:#eee;border-radius:4px}
button.on{background:#333;color:#fff}
.row{display:flex;align-items:center;gap:6px;margin:2px 0}
.sw{width:14px;height:14px;border:1px solid #0004;flex:none}
#help{position:absolute;left:10px;bottom:8px;color:#666}
#nogl{position:absolute;top:40%;width:100%;text-align:center;display:none}
</style></head><body>
<canvas id="view"></canvas>
<div id="panel"><h1>__TITLE__</h1>
<div><button id="bi" class="on">instances (i)</button><button id="bc">classes (c)</button></div>
<div id="stats"></div><div id="legend"></div></div>
<div id="help">drag: orbit · shift-drag: pan · wheel: zoom · r: reset</div>
<div id="nogl">This page needs WebGL.</div>
<script>
"use strict";
const D = __DATA__;
function bytes(b64){const s=atob(b64),a=new Uint8Array(s.length);for(let i=0;i<s.length;i++)a[i]=s.charCodeAt(i);return a;}
const pos=new Float32Array(bytes(D.positions).buffer), cols=[bytes(D.instanceColors),bytes(D.classColors)];
const isMesh=!!D.indices, idx=isMesh?new Uint32Array(bytes(D.indices).buffer):null;
const nrm=isMesh?new Float32Array(bytes(D.normals).buffer):null;
const canvas=document.getElementById("view");
const gl=canvas.getContext("webgl",{preserveDrawingBuffer:true,antialias:true});
// Legend and stats do not need WebGL.
document.getElementById("stats").textContent=(isMesh?(idx.length/3)+" triangles, ":"")+D.count+" "+
  (isMesh?"vertices":"points")+", "+D.instances+(D.instances===1?" instance":" instances");
const leg=document.getElementById("legend");
for(const c of D.legend){const r=document.createElement("div");r.className="row";const s=document.createElement("span");
  s.className="sw";s.style.background="rgb("+c.color.join(",")+")";const t=document.createElement("span");
  t.textContent=c.name+" ("+c.count+")";r.append(s,t);leg.append(r);}
if(!gl){document.getElementById("nogl").style.display="block";}
else{
const vs=`attribute vec3 p;attribute vec3 c;attribute vec3 n;uniform mat4 mvp;uniform float ps;uniform float lit;
varying vec3 vc;void main(){gl_Position=mvp*vec4(p,1.0);gl_PointSize=ps;
float l=lit>0.5?0.45+0.55*abs(dot(normalize(n),normalize(vec3(0.3,0.5,0.8)))):1.0;vc=c*l;}`;
const fs=`precision mediump float;varying vec3 vc;uniform float round;void main(){
if(round>0.5){vec2 d=gl_PointCoord-vec2(0.5);if(dot(d,d)>0.25)discard;}gl_FragColor=vec4(vc,1.0);}`;
function sh(t,s){const o=gl.createShader(t);gl.shaderSource(o,s);gl.compileShader(o);return o;}
const prog=gl.createProgram();gl.attachShader(prog,sh(gl.VERTEX_SHADER,vs));gl.attachShader(prog,sh(gl.FRAGMENT_SHADER,fs));
gl.linkProgram(prog);gl.useProgram(prog);
if(isMesh&&!gl.getExtension("OES_element_index_uint"))document.getElementById("nogl").textContent="This mesh needs 32-bit indices.";
function buf(data,attr,size,norm,type){const b=gl.createBuffer();gl.bindBuffer(gl.ARRAY_BUFFER,b);gl.bufferData(gl.ARRAY_BUFFER,data,gl.STATIC_DRAW);
  const loc=gl.getAttribLocation(prog,attr);return {b,loc,size,norm,type};}
function bind(a){if(a.loc<0)return;gl.bindBuffer(gl.ARRAY_BUFFER,a.b);gl.enableVertexAttribArray(a.loc);gl.vertexAttribPointer(a.loc,a.size,a.type,a.norm,0,0);}
const aP=buf(pos,"p",3,false,gl.FLOAT), aC=[buf(cols[0],"c",3,true,gl.UNSIGNED_BYTE),buf(cols[1],"c",3,true,gl.UNSIGNED_BYTE)];
const aN=isMesh?buf(nrm,"n",3,false,gl.FLOAT):null;
if(!isMesh){const l=gl.getAttribLocation(prog,"n");if(l>=0){gl.disableVertexAttribArray(l);gl.vertexAttrib3f(l,0,0,1);}}
let ib=null;if(isMesh){ib=gl.createBuffer();gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER,ib);gl.bufferData(gl.ELEMENT_ARRAY_BUFFER,idx,gl.STATIC_DRAW);}
const U=n=>gl.getUniformLocation(prog,n);
gl.enable(gl.DEPTH_TEST);
let mode=0;const up=D.up;
// Orbit camera about the up axis: yaw around up, pitch above the horizon, distance.
let yaw=0.8,pitch=0.55,dist=2.6,target=[0,0,0];
function basis(){const u=up;const a=Math.abs(u[0])<0.9?[1,0,0]:[0,1,0];const x=norm(cross(a,u));const y=cross(u,x);return [x,y,u];}
function cross(a,b){return [a[1]*b[2]-a[2]*b[1],a[2]*b[0]-a[0]*b[2],a[0]*b[1]-a[1]*b[0]];}
function norm(a){const l=Math.hypot(a[0],a[1],a[2])||1;return [a[0]/l,a[1]/l,a[2]/l];}
function sub(a,b){return [a[0]-b[0],a[1]-b[1],a[2]-b[2]];}
function dot(a,b){return a[0]*b[0]+a[1]*b[1]+a[2]*b[2];}
function eye(){const [x,y,u]=basis();const c=Math.cos(pitch),s=Math.sin(pitch);
  const d=[0,1,2].map(i=>(x[i]*Math.cos(yaw)+y[i]*Math.sin(yaw))*c+u[i]*s);return [0,1,2].map(i=>target[i]+dist*d[i]);}
function lookAt(e,t,u){const f=norm(sub(t,e)),s=norm(cross(f,u)),v=cross(s,f);
  return [s[0],v[0],-f[0],0,s[1],v[1],-f[1],0,s[2],v[2],-f[2],0,-dot(s,e),-dot(v,e),dot(f,e),1];}
function persp(fy,a,n,f){const t=1/Math.tan(fy/2);return [t/a,0,0,0,0,t,0,0,0,0,(f+n)/(n-f),-1,0,0,2*f*n/(n-f),0];}
function mul(a,b){const o=new Array(16).fill(0);for(let i=0;i<4;i++)for(let j=0;j<4;j++)for(let k=0;k<4;k++)o[j*4+i]+=a[k*4+i]*b[j*4+k];return o;}
function draw(){const w=canvas.clientWidth,h=canvas.clientHeight,r=window.devicePixelRatio||1;
  if(canvas.width!==Math.round(w*r)||canvas.height!==Math.round(h*r)){canvas.width=Math.round(w*r);canvas.height=Math.round(h*r);}
  gl.viewport(0,0,canvas.width,canvas.height);gl.clearColor(1,1,1,1);gl.clear(gl.COLOR_BUFFER_BIT|gl.DEPTH_BUFFER_BIT);
  const m=mul(persp(0.8,canvas.width/Math.max(canvas.height,1),dist*0.02,dist*4),lookAt(eye(),target,up));
  gl.uniformMatrix4fv(U("mvp"),false,new Float32Array(m));gl.uniform1f(U("ps"),D.pointSize*r);
  gl.uniform1f(U("lit"),isMesh?1:0);gl.uniform1f(U("round"),isMesh?0:1);
  bind(aP);bind(aC[mode]);if(aN)bind(aN);
  if(isMesh)gl.drawElements(gl.TRIANGLES,idx.length,gl.UNSIGNED_INT,0);else gl.drawArrays(gl.POINTS,0,D.count);}
function setMode(m){mode=m;document.getElementById("bi").className=m===0?"on":"";document.getElementById("bc").className=m===1?"on":"";draw();}
document.getElementById("bi").onclick=()=>setMode(0);document.getElementById("bc").onclick=()=>setMode(1);
let drag=null;canvas.onmousedown=e=>{drag={x:e.clientX,y:e.clientY,pan:e.shiftKey};canvas.style.cursor="grabbing";};
window.onmouseup=()=>{drag=null;canvas.style.cursor="grab";};
window.onmousemove=e=>{if(!drag)return;const dx=e.clientX-drag.x,dy=e.clientY-drag.y;drag.x=e.clientX;drag.y=e.clientY;
  if(drag.pan){const ev=eye(),f=norm(sub(target,ev)),s=norm(cross(f,up)),v=cross(s,f),k=dist*0.0015;
    target=[0,1,2].map(i=>target[i]-s[i]*dx*k+v[i]*dy*k);}
  else{yaw-=dx*0.008;pitch=Math.max(-1.5,Math.min(1.5,pitch+dy*0.008));}draw();};
canvas.addEventListener("wheel",e=>{e.preventDefault();dist*=Math.exp(e.deltaY*0.001);draw();},{passive:false});
window.onkeydown=e=>{if(e.key==="i")setMode(0);if(e.key==="c")setMode(1);if(e.key==="r"){yaw=0.8;pitch=0.55;dist=2.6;target=[0,0,0];draw();}};
window.onresize=draw;
if(location.hash==="#classes")setMode(1);else draw();
}
</script></body></html>
"""
