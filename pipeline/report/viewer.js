/* psrig 3-D mesh viewer: a small self-contained viewer for the session report.
 *
 * Draws every <canvas class="psrig-mesh" data-mesh="KEY"> with the mesh that a mesh script
 * (mesh.js, loaded before this file) stored in window.PSRIG_MESHES[KEY]: positions (float32,
 * centred, longest side 2), normals (int8 x 127, from photometric stereo), colours (uint8 sRGB
 * albedo, optional) and triangles (uint16), each base64-encoded. WebGL when the browser has it,
 * else a 2-D canvas painter's algorithm (add #canvas2d to the page's address to force it).
 * Drag to rotate, wheel to zoom, double-click (or the reset button) to reset; arrow keys and
 * +/- when the canvas has the focus. No network, no libraries: it opens from disk.
 * The canvas records what drew it: data-renderer = webgl | canvas2d | none, data-drawn = 1.
 * psrig is MIT-licensed; so is this file.
 */
(function () {
  "use strict";

  var LIGHT = normalise([0.35, 0.45, 0.82]); // a headlight from the upper left, in view space
  var BACKGROUND = [0.957, 0.957, 0.957];

  function decode(text, Type) {
    var raw = atob(text), bytes = new Uint8Array(raw.length);
    for (var i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  function normalise(v) {
    var n = Math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) || 1;
    return [v[0] / n, v[1] / n, v[2] / n];
  }

  // Column-major 4x4 matrices, as WebGL takes them.
  function multiply(a, b) {
    var out = new Float32Array(16);
    for (var c = 0; c < 4; c++)
      for (var r = 0; r < 4; r++) {
        var s = 0;
        for (var k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
        out[c * 4 + r] = s;
      }
    return out;
  }

  function rotation(yaw, pitch) {
    var cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    // R = Rx(pitch) * Ry(yaw)
    return new Float32Array([cy, sp * sy, -cp * sy, 0, 0, cp, sp, 0, sy, -sp * cy, cp * cy, 0, 0, 0, 0, 1]);
  }

  function perspective(aspect, distance) {
    var f = 1 / Math.tan(Math.PI / 12), near = 0.05, far = distance + 10; // 30 degree field of view
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
                             0, 0, (2 * far * near) / (near - far), 0]);
  }

  function translation(z) {
    return new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -z, 1]);
  }

  function Mesh(data) {
    this.positions = decode(data.positions, Float32Array);
    this.normals = decode(data.normals, Int8Array);
    this.colours = data.colours ? decode(data.colours, Uint8Array) : null;
    this.indices = decode(data.indices, Uint16Array);
    this.vertices = this.positions.length / 3;
    this.faces = this.indices.length / 3;
  }

  function View(canvas, mesh) {
    this.canvas = canvas;
    this.mesh = mesh;
    this.colour = !!mesh.colours;
    this.reset();
    var force2d = /canvas2d/.test(window.location.hash) || canvas.dataset.request === "canvas2d";
    this.painter = (!force2d && WebGLPainter.create(canvas, mesh)) || CanvasPainter.create(canvas, mesh);
    canvas.dataset.renderer = this.painter ? this.painter.name : "none";
    this.bind();
    this.request();
  }

  View.prototype.reset = function () {
    // a little from the side and below the camera's view, so that the relief shows at once
    this.yaw = 0.35;
    this.pitch = 0.3;
    this.zoom = 1;
    this.request();
  };

  View.prototype.request = function () {
    var self = this;
    if (this.pending || !this.painter) return;
    this.pending = true;
    window.requestAnimationFrame(function () {
      self.pending = false;
      self.draw();
    });
  };

  View.prototype.draw = function () {
    var distance = 4.2 / this.zoom;
    var rot = rotation(this.yaw, this.pitch);
    var aspect = this.canvas.width / this.canvas.height;
    var mvp = multiply(perspective(aspect, distance), multiply(translation(distance), rot));
    this.painter.draw(mvp, rot, distance, this.colour);
    this.canvas.dataset.drawn = "1";
  };

  View.prototype.bind = function () {
    var self = this, canvas = this.canvas, last = null;
    canvas.addEventListener("pointerdown", function (e) {
      last = [e.clientX, e.clientY];
      if (canvas.setPointerCapture) canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", function (e) {
      if (!last) return;
      self.yaw += (e.clientX - last[0]) * 0.01;
      self.pitch = Math.max(-1.55, Math.min(1.55, self.pitch + (e.clientY - last[1]) * 0.01));
      last = [e.clientX, e.clientY];
      self.request();
    });
    canvas.addEventListener("pointerup", function () { last = null; });
    canvas.addEventListener("pointercancel", function () { last = null; });
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      self.zoom = Math.max(0.3, Math.min(12, self.zoom * Math.exp(-e.deltaY * 0.0015)));
      self.request();
    }, { passive: false });
    canvas.addEventListener("dblclick", function () { self.reset(); });
    canvas.addEventListener("keydown", function (e) {
      var step = { ArrowLeft: [-0.1, 0], ArrowRight: [0.1, 0], ArrowUp: [0, -0.1], ArrowDown: [0, 0.1] }[e.key];
      if (step) { self.yaw += step[0]; self.pitch += step[1]; }
      else if (e.key === "+" || e.key === "=") self.zoom *= 1.2;
      else if (e.key === "-") self.zoom /= 1.2;
      else if (e.key === "0") self.reset();
      else return;
      e.preventDefault();
      self.request();
    });
  };

  var WebGLPainter = {
    name: "webgl",
    create: function (canvas, mesh) {
      var gl = null;
      try {
        gl = canvas.getContext("webgl", { preserveDrawingBuffer: true, antialias: true });
      } catch (err) {
        gl = null;
      }
      if (!gl) return null;
      var vs = "attribute vec3 p; attribute vec3 n; attribute vec3 c; uniform mat4 mvp; uniform mat4 rot;" +
        "varying vec3 vn; varying vec3 vc;" +
        "void main() { gl_Position = mvp * vec4(p, 1.0); vn = (rot * vec4(n, 0.0)).xyz; vc = c; }";
      var fs = "precision mediump float; uniform vec3 light; uniform float tint; varying vec3 vn; varying vec3 vc;" +
        "void main() { float d = abs(dot(normalize(vn), light));" +
        "vec3 base = mix(vec3(0.82), vc, tint); gl_FragColor = vec4(base * (0.18 + 0.82 * d), 1.0); }";
      var program = link(gl, vs, fs);
      if (!program) return null;
      var painter = Object.create(WebGLPainter);
      painter.gl = gl;
      painter.program = program;
      painter.count = mesh.indices.length;
      buffer(gl, program, "p", mesh.positions, 3, gl.FLOAT, false);
      buffer(gl, program, "n", mesh.normals, 3, gl.BYTE, true);
      var colours = mesh.colours || new Uint8Array(mesh.vertices * 3).fill(209);
      buffer(gl, program, "c", colours, 3, gl.UNSIGNED_BYTE, true);
      var index = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, index);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, mesh.indices, gl.STATIC_DRAW);
      gl.enable(gl.DEPTH_TEST);
      return painter;
    },
    draw: function (mvp, rot, distance, colour) {
      var gl = this.gl, program = this.program;
      gl.viewport(0, 0, gl.drawingBufferWidth, gl.drawingBufferHeight);
      gl.clearColor(BACKGROUND[0], BACKGROUND[1], BACKGROUND[2], 1);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.useProgram(program);
      gl.uniformMatrix4fv(gl.getUniformLocation(program, "mvp"), false, mvp);
      gl.uniformMatrix4fv(gl.getUniformLocation(program, "rot"), false, rot);
      gl.uniform3fv(gl.getUniformLocation(program, "light"), LIGHT);
      gl.uniform1f(gl.getUniformLocation(program, "tint"), colour ? 1 : 0);
      gl.drawElements(gl.TRIANGLES, this.count, gl.UNSIGNED_SHORT, 0);
    }
  };

  function link(gl, vsText, fsText) {
    var program = gl.createProgram();
    [[gl.VERTEX_SHADER, vsText], [gl.FRAGMENT_SHADER, fsText]].forEach(function (part) {
      var shader = gl.createShader(part[0]);
      gl.shaderSource(shader, part[1]);
      gl.compileShader(shader);
      gl.attachShader(program, shader);
    });
    gl.linkProgram(program);
    return gl.getProgramParameter(program, gl.LINK_STATUS) ? program : null;
  }

  function buffer(gl, program, name, data, size, type, normalised) {
    var where = gl.getAttribLocation(program, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(where);
    gl.vertexAttribPointer(where, size, type, normalised, 0, 0);
  }

  var CanvasPainter = {
    name: "canvas2d",
    create: function (canvas, mesh) {
      var ctx = canvas.getContext("2d");
      if (!ctx) return null;
      var painter = Object.create(CanvasPainter);
      painter.ctx = ctx;
      painter.mesh = mesh;
      painter.order = new Uint32Array(mesh.faces);
      painter.depth = new Float32Array(mesh.faces);
      return painter;
    },
    draw: function (mvp, rot, distance, colour) {
      var ctx = this.ctx, mesh = this.mesh, w = ctx.canvas.width, h = ctx.canvas.height;
      var P = mesh.positions, N = mesh.normals, C = mesh.colours, I = mesh.indices, V = mesh.vertices;
      var sx = new Float32Array(V), sy = new Float32Array(V), sz = new Float32Array(V);
      for (var v = 0; v < V; v++) {
        var x = P[3 * v], y = P[3 * v + 1], z = P[3 * v + 2];
        var cx = mvp[0] * x + mvp[4] * y + mvp[8] * z + mvp[12];
        var cy = mvp[1] * x + mvp[5] * y + mvp[9] * z + mvp[13];
        var cw = mvp[3] * x + mvp[7] * y + mvp[11] * z + mvp[15];
        sx[v] = (cx / cw + 1) * 0.5 * w;
        sy[v] = (1 - cy / cw) * 0.5 * h;
        sz[v] = cw; // distance along the view: paint the far faces first
      }
      var order = this.order, depth = this.depth, F = mesh.faces;
      for (var f = 0; f < F; f++) {
        order[f] = f;
        depth[f] = sz[I[3 * f]] + sz[I[3 * f + 1]] + sz[I[3 * f + 2]];
      }
      Array.prototype.sort.call(order, function (a, b) { return depth[b] - depth[a]; });
      ctx.fillStyle = "rgb(244,244,244)";
      ctx.fillRect(0, 0, w, h);
      ctx.lineWidth = 0.6;
      for (var k = 0; k < F; k++) {
        var t = order[k], a = I[3 * t], b = I[3 * t + 1], c = I[3 * t + 2];
        var nx = N[3 * a] + N[3 * b] + N[3 * c], ny = N[3 * a + 1] + N[3 * b + 1] + N[3 * c + 1];
        var nz = N[3 * a + 2] + N[3 * b + 2] + N[3 * c + 2];
        var rx = rot[0] * nx + rot[4] * ny + rot[8] * nz, ry = rot[1] * nx + rot[5] * ny + rot[9] * nz;
        var rz = rot[2] * nx + rot[6] * ny + rot[10] * nz;
        var shade = 0.18 + 0.82 * Math.abs(rx * LIGHT[0] + ry * LIGHT[1] + rz * LIGHT[2]) /
          (Math.sqrt(rx * rx + ry * ry + rz * rz) || 1);
        var r = 209, g = 209, bl = 209;
        if (colour && C) {
          r = (C[3 * a] + C[3 * b] + C[3 * c]) / 3;
          g = (C[3 * a + 1] + C[3 * b + 1] + C[3 * c + 1]) / 3;
          bl = (C[3 * a + 2] + C[3 * b + 2] + C[3 * c + 2]) / 3;
        }
        var style = "rgb(" + (r * shade | 0) + "," + (g * shade | 0) + "," + (bl * shade | 0) + ")";
        ctx.fillStyle = style;
        ctx.strokeStyle = style; // covers the seams that antialiasing leaves between triangles
        ctx.beginPath();
        ctx.moveTo(sx[a], sy[a]);
        ctx.lineTo(sx[b], sy[b]);
        ctx.lineTo(sx[c], sy[c]);
        ctx.closePath();
        ctx.fill();
        ctx.stroke();
      }
    }
  };

  function start() {
    var meshes = window.PSRIG_MESHES || {};
    var canvases = document.querySelectorAll("canvas.psrig-mesh");
    for (var i = 0; i < canvases.length; i++) {
      var canvas = canvases[i], data = meshes[canvas.dataset.mesh];
      var note = document.getElementById(canvas.id + "-note");
      if (!data) {
        canvas.dataset.renderer = "none";
        if (note) note.textContent = "3-D view: the mesh data (" + canvas.dataset.mesh + ") is missing.";
        continue;
      }
      var view = new View(canvas, new Mesh(data));
      canvas.psrigView = view;
      if (note) {
        note.textContent = view.painter
          ? (view.painter.name === "webgl" ? "WebGL" : "2-D canvas (no WebGL here)") + ": " +
            view.mesh.vertices + " vertices, " + view.mesh.faces + " faces. Drag to rotate, wheel to zoom, " +
            "double-click to reset."
          : "3-D view: this browser draws neither WebGL nor a 2-D canvas.";
      }
      bindControls(canvas.id, view);
    }
  }

  function bindControls(id, view) {
    var reset = document.getElementById(id + "-reset"), tint = document.getElementById(id + "-colour");
    if (reset) reset.addEventListener("click", function () { view.reset(); });
    if (tint) {
      tint.disabled = !view.mesh.colours;
      tint.checked = view.colour;
      tint.addEventListener("change", function () { view.colour = tint.checked; view.request(); });
    }
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
