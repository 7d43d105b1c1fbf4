/* psrig relighting viewer: the fitted reflectance model of a session under a light you drag.
 *
 * Draws every <canvas class="psrig-relight" data-relight="KEY"> from the data a script
 * (relight_KEY.js, loaded before this file) stored in window.PSRIG_RELIGHT[KEY]: a grid of
 * width x height pixels, a mask (uint8) and per object pixel 16 float32 values (normal x, y, z,
 * 1, the paper's Eq. 2 coefficients A..I relative to the albedo, linear albedo R, G, B), base64.
 * Per pixel, for the light l (unit, camera frame: x right, y up, z toward the camera) and the
 * view v = (0, 0, 1): h = (l + v) / |l + v|, x = n.h, y = l.h,
 *   rho = A x^2 y^2 + B x^2 y + C x^2 + D x y^2 + E x y + F x + G y^2 + H y + I,
 *   model: albedo * rho * max(n.l, 0); diffuse: albedo * max(n.l, 0);
 *   normals: grey 0.7 max(n.l, 0) + 0.3 max(n.h, 0)^40 (lit side only), a fixed material;
 * shown as sRGB of value * 2^exposure / white. Mode "frame" shows the captured frame whose light
 * is nearest. WebGL (float textures, per-pixel in the fragment shader) when the browser has it,
 * else a 2-D canvas evaluating the same formula (add #canvas2d to the address to force it).
 * Drag on the disc (or on the image) with a mouse, pen or finger; arrow keys when focused.
 * window.psrigRelight.setLight(x, y, z[, key]) / setMode(mode[, key]) / setExposure(stops[, key])
 * draw at once (for tests and scripting). No network, no libraries: it opens from disk.
 * psrig is MIT-licensed; so is this file.
 */
(function () {
  "use strict";

  var BACKGROUND = [0.957, 0.957, 0.957];
  var MODES = { model: 0, diffuse: 1, normals: 2, frame: 3 };
  var MATERIAL = { diffuse: 0.7, specular: 0.3, exponent: 40.0 };

  function decode(text, Type) {
    var raw = atob(text), bytes = new Uint8Array(raw.length);
    for (var i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  function normalise(v) {
    var n = Math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) || 1;
    return [v[0] / n, v[1] / n, v[2] / n];
  }

  function halfVector(l) {
    return normalise([l[0], l[1], l[2] + 1]);
  }

  function srgb(c) {
    c = c < 0 ? 0 : (c > 1 ? 1 : c);
    return c <= 0.0031308 ? 12.92 * c : 1.055 * Math.pow(c, 1 / 2.4) - 0.055;
  }

  // The model's grid as four RGBA float planes of width x height (zero off the object).
  function Model(data) {
    var w = data.width, h = data.height, mask = decode(data.mask, Uint8Array);
    var values = decode(data.values, Float32Array);
    this.width = w;
    this.height = h;
    this.planes = [0, 1, 2, 3].map(function () { return new Float32Array(w * h * 4); });
    var k = 0;
    for (var p = 0; p < w * h; p++) {
      if (!mask[p]) continue;
      for (var t = 0; t < 4; t++)
        for (var c = 0; c < 4; c++) this.planes[t][p * 4 + c] = values[k * 16 + t * 4 + c];
      k++;
    }
    this.pixels = k;
  }

  function View(key, canvas, data) {
    this.key = key;
    this.canvas = canvas;
    this.data = data;
    this.model = new Model(data);
    this.light = normalise(data.light || [0, 0, 1]);
    this.mode = "model";
    this.exposure = 0;
    this.frameImage = document.getElementById(canvas.id + "-frame");
    this.dome = document.getElementById(canvas.id + "-dome");
    this.readout = document.getElementById(canvas.id + "-readout");
    var force2d = /canvas2d/.test(window.location.hash) || canvas.dataset.request === "canvas2d";
    this.painter = (!force2d && GLPainter.create(canvas, this.model)) || CanvasPainter.create(canvas, this.model);
    canvas.dataset.renderer = this.painter ? this.painter.name : "none";
    this.bind();
    this.draw();
  }

  View.prototype.setLight = function (x, y, z) {
    var l = normalise([x, y, Math.max(z, 0)]);
    if (!(l[0] || l[1] || l[2])) l = [0, 0, 1];
    this.light = l;
    this.draw();
  };

  View.prototype.nearestFrame = function () {
    var best = null, bestDot = -2, lights = this.data.lights || [], frames = this.data.frames || [];
    for (var i = 0; i < frames.length; i++) {
      var d = lights[frames[i].light];
      if (!d) continue;
      var dot = d[0] * this.light[0] + d[1] * this.light[1] + d[2] * this.light[2];
      if (dot > bestDot) { bestDot = dot; best = frames[i]; }
    }
    return best ? { frame: best, degrees: Math.acos(Math.min(1, Math.max(-1, bestDot))) * 180 / Math.PI } : null;
  };

  View.prototype.draw = function () {
    var frameMode = this.mode === "frame" && this.frameImage;
    var nearest = this.nearestFrame();
    if (frameMode) {
      this.canvas.hidden = true;
      this.frameImage.hidden = false;
      if (nearest && this.frameImage.getAttribute("src") !== nearest.frame.thumb) this.frameImage.src = nearest.frame.thumb;
    } else {
      if (this.frameImage) this.frameImage.hidden = true;
      this.canvas.hidden = false;
      if (this.painter) {
        var gain = Math.pow(2, this.exposure) / (this.mode === "normals" ? 1 : this.data.white);
        this.painter.draw(this.light, halfVector(this.light), MODES[this.mode], gain);
      }
    }
    this.canvas.dataset.drawn = "1";
    this.drawDome();
    if (this.readout) {
      var l = this.light, polar = Math.acos(l[2]) * 180 / Math.PI, azimuth = Math.atan2(l[1], l[0]) * 180 / Math.PI;
      var text = "light (" + l[0].toFixed(3) + ", " + l[1].toFixed(3) + ", " + l[2].toFixed(3) + ")\n" +
        "polar " + polar.toFixed(1) + "\u00b0, azimuth " + azimuth.toFixed(1) + "\u00b0";
      if (nearest) text += "\nnearest captured: " + nearest.frame.id + " (light " + nearest.frame.light + "), " +
        nearest.degrees.toFixed(1) + "\u00b0 away";
      this.readout.textContent = text;
      this.readout.style.whiteSpace = "pre-line";
    }
  };

  View.prototype.drawDome = function () {
    var dome = this.dome;
    if (!dome || !dome.getContext) return;
    var ctx = dome.getContext("2d"), w = dome.width, h = dome.height, r = Math.min(w, h) / 2 - 6;
    var cx = w / 2, cy = h / 2;
    ctx.clearRect(0, 0, w, h);
    ctx.fillStyle = "#f4f4f4";
    ctx.strokeStyle = "#999";
    ctx.beginPath();
    ctx.arc(cx, cy, r, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
    ctx.strokeStyle = "#ddd";
    [30, 60].forEach(function (deg) {
      ctx.beginPath();
      ctx.arc(cx, cy, r * Math.sin(deg * Math.PI / 180), 0, 2 * Math.PI);
      ctx.stroke();
    });
    ctx.fillStyle = "#888";
    (this.data.lights || []).forEach(function (d) {
      ctx.beginPath();
      ctx.arc(cx + d[0] * r, cy - d[1] * r, 2, 0, 2 * Math.PI);
      ctx.fill();
    });
    ctx.fillStyle = "#f0b020";
    ctx.strokeStyle = "#805000";
    ctx.beginPath();
    ctx.arc(cx + this.light[0] * r, cy - this.light[1] * r, 6, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
  };

  // A pointer position on ``element`` as a light: the disc's (or the image's) centre is the
  // view axis, its rim the horizon.
  View.prototype.lightAt = function (element, clientX, clientY, disc) {
    var box = element.getBoundingClientRect();
    var r = Math.min(box.width, box.height) / 2 - (disc ? 6 * box.width / element.width : 0);
    var x = (clientX - box.left - box.width / 2) / r, y = -(clientY - box.top - box.height / 2) / r;
    var d = Math.sqrt(x * x + y * y);
    if (d > 0.999) { x *= 0.999 / d; y *= 0.999 / d; d = 0.999; }
    this.setLight(x, y, Math.sqrt(1 - d * d));
  };

  View.prototype.bind = function () {
    var self = this;
    [[this.dome, true], [this.canvas, false]].forEach(function (pair) {
      var element = pair[0], disc = pair[1], down = false;
      if (!element) return;
      element.addEventListener("pointerdown", function (e) {
        down = true;
        try {
          if (element.setPointerCapture) element.setPointerCapture(e.pointerId);
        } catch (err) { /* a pointer the browser does not track (synthetic events): dragging still works */ }
        self.lightAt(element, e.clientX, e.clientY, disc);
        e.preventDefault();
      });
      element.addEventListener("pointermove", function (e) {
        if (down) self.lightAt(element, e.clientX, e.clientY, disc);
      });
      element.addEventListener("pointerup", function () { down = false; });
      element.addEventListener("pointercancel", function () { down = false; });
    });
    this.canvas.addEventListener("keydown", function (e) {
      var step = { ArrowLeft: [-0.05, 0], ArrowRight: [0.05, 0], ArrowUp: [0, 0.05], ArrowDown: [0, -0.05] }[e.key];
      if (!step) return;
      var x = self.light[0] + step[0], y = self.light[1] + step[1];
      var d = Math.sqrt(x * x + y * y);
      if (d > 0.999) { x *= 0.999 / d; y *= 0.999 / d; d = 0.999; }
      self.setLight(x, y, Math.sqrt(1 - d * d));
      e.preventDefault();
    });
    var radios = document.querySelectorAll("input[name='" + this.canvas.id + "-mode']");
    for (var i = 0; i < radios.length; i++)
      radios[i].addEventListener("change", function (e) { if (e.target.checked) self.setMode(e.target.value); });
    var exposure = document.getElementById(this.canvas.id + "-exposure");
    if (exposure) exposure.addEventListener("input", function () { self.exposure = parseFloat(exposure.value) || 0; self.draw(); });
  };

  View.prototype.setMode = function (mode) {
    if (!(mode in MODES)) throw new Error("psrig relight: unknown mode " + mode);
    this.mode = mode;
    var radios = document.querySelectorAll("input[name='" + this.canvas.id + "-mode']");
    for (var i = 0; i < radios.length; i++) radios[i].checked = radios[i].value === mode;
    this.draw();
  };

  var GLPainter = {
    name: "webgl",
    create: function (canvas, model) {
      var gl = null;
      try {
        gl = canvas.getContext("webgl", { preserveDrawingBuffer: true, antialias: false });
      } catch (err) {
        gl = null;
      }
      if (!gl || !gl.getExtension("OES_texture_float")) return null;
      var high = gl.getShaderPrecisionFormat(gl.FRAGMENT_SHADER, gl.HIGH_FLOAT);
      if (!high || high.precision < 16) return null;  // the coefficients cancel: mediump is not enough
      var vs = "attribute vec2 p; varying vec2 uv;" +
        "void main() { uv = vec2(p.x * 0.5 + 0.5, 0.5 - p.y * 0.5); gl_Position = vec4(p, 0.0, 1.0); }";
      var fs = "precision highp float; uniform sampler2D t0; uniform sampler2D t1; uniform sampler2D t2;" +
        "uniform sampler2D t3; uniform vec3 light; uniform vec3 hv; uniform float gain; uniform int mode;" +
        "uniform vec3 background; varying vec2 uv;" +
        "vec3 srgb(vec3 c) { c = clamp(c, 0.0, 1.0);" +
        "  return mix(12.92 * c, 1.055 * pow(max(c, vec3(1e-10)), vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c)); }" +
        "void main() { vec4 a = texture2D(t0, uv);" +
        "  if (a.w < 0.5) { gl_FragColor = vec4(background, 1.0); return; }" +
        "  vec3 n = a.xyz; float s = max(dot(n, light), 0.0); float x = dot(n, hv); float y = dot(light, hv);" +
        "  vec4 b = texture2D(t1, uv); vec4 c = texture2D(t2, uv); vec4 d = texture2D(t3, uv); vec3 col;" +
        "  if (mode == 0) { float y2 = y * y;" +
        "    float rho = (b.x * y2 + b.y * y + b.z) * x * x + (b.w * y2 + c.x * y + c.y) * x + (c.z * y2 + c.w * y + d.x);" +
        "    col = d.yzw * (rho * s); }" +
        "  else if (mode == 1) { col = d.yzw * s; }" +
        "  else { float g = " + MATERIAL.diffuse.toFixed(3) + " * s;" +
        "    if (s > 0.0) g += " + MATERIAL.specular.toFixed(3) + " * pow(max(x, 1e-10), " + MATERIAL.exponent.toFixed(1) + ");" +
        "    col = vec3(g); }" +
        "  gl_FragColor = vec4(srgb(col * gain), 1.0); }";
      var program = link(gl, vs, fs);
      if (!program) return null;
      var painter = Object.create(GLPainter);
      painter.gl = gl;
      painter.program = program;
      gl.useProgram(program);
      var quad = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, quad);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
      var where = gl.getAttribLocation(program, "p");
      gl.enableVertexAttribArray(where);
      gl.vertexAttribPointer(where, 2, gl.FLOAT, false, 0, 0);
      for (var t = 0; t < 4; t++) {
        gl.activeTexture(gl.TEXTURE0 + t);
        gl.bindTexture(gl.TEXTURE_2D, gl.createTexture());
        gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, model.width, model.height, 0, gl.RGBA, gl.FLOAT, model.planes[t]);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
        gl.uniform1i(gl.getUniformLocation(program, "t" + t), t);
      }
      if (gl.getError() !== gl.NO_ERROR) return null;
      return painter;
    },
    draw: function (light, hv, mode, gain) {
      var gl = this.gl, program = this.program;
      gl.viewport(0, 0, gl.drawingBufferWidth, gl.drawingBufferHeight);
      gl.useProgram(program);
      gl.uniform3fv(gl.getUniformLocation(program, "light"), light);
      gl.uniform3fv(gl.getUniformLocation(program, "hv"), hv);
      gl.uniform1f(gl.getUniformLocation(program, "gain"), gain);
      gl.uniform1i(gl.getUniformLocation(program, "mode"), mode);
      gl.uniform3fv(gl.getUniformLocation(program, "background"), BACKGROUND);
      gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
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

  var CanvasPainter = {
    name: "canvas2d",
    create: function (canvas, model) {
      var ctx = canvas.getContext("2d");
      if (!ctx) return null;
      var painter = Object.create(CanvasPainter);
      painter.ctx = ctx;
      painter.model = model;
      painter.image = ctx.createImageData(model.width, model.height);
      return painter;
    },
    draw: function (light, hv, mode, gain) {
      var m = this.model, out = this.image.data, P = m.planes, count = m.width * m.height;
      var y = light[0] * hv[0] + light[1] * hv[1] + light[2] * hv[2], y2 = y * y;
      var bg = BACKGROUND.map(function (v) { return Math.round(v * 255); });
      for (var p = 0; p < count; p++) {
        var i = p * 4, a = P[0], r, g, b;
        if (a[i + 3] < 0.5) {
          out[i] = bg[0]; out[i + 1] = bg[1]; out[i + 2] = bg[2]; out[i + 3] = 255;
          continue;
        }
        var nx = a[i], ny = a[i + 1], nz = a[i + 2];
        var s = Math.max(nx * light[0] + ny * light[1] + nz * light[2], 0);
        var x = nx * hv[0] + ny * hv[1] + nz * hv[2];
        var B = P[1], C = P[2], D = P[3];
        if (mode === 2) {
          var grey = MATERIAL.diffuse * s + (s > 0 ? MATERIAL.specular * Math.pow(Math.max(x, 0), MATERIAL.exponent) : 0);
          r = g = b = grey;
        } else {
          var f = s;
          if (mode === 0) {
            f *= (B[i] * y2 + B[i + 1] * y + B[i + 2]) * x * x + (B[i + 3] * y2 + C[i] * y + C[i + 1]) * x +
              (C[i + 2] * y2 + C[i + 3] * y + D[i]);
          }
          r = D[i + 1] * f; g = D[i + 2] * f; b = D[i + 3] * f;
        }
        out[i] = Math.round(255 * srgb(r * gain));
        out[i + 1] = Math.round(255 * srgb(g * gain));
        out[i + 2] = Math.round(255 * srgb(b * gain));
        out[i + 3] = 255;
      }
      this.ctx.putImageData(this.image, 0, 0);
    }
  };

  var views = {};

  function start() {
    var data = window.PSRIG_RELIGHT || {};
    var canvases = document.querySelectorAll("canvas.psrig-relight");
    for (var i = 0; i < canvases.length; i++) {
      var canvas = canvases[i], key = canvas.dataset.relight, note = document.getElementById(canvas.id + "-note");
      if (!data[key]) {
        canvas.dataset.renderer = "none";
        if (note) note.textContent = "Relighting view: the model data (" + key + ") is missing.";
        continue;
      }
      var view = new View(key, canvas, data[key]);
      views[key] = view;
      canvas.psrigRelight = view;
      if (note) {
        note.textContent = view.painter
          ? (view.painter.name === "webgl" ? "WebGL" : "2-D canvas (no WebGL with float textures here)") + ": " +
            view.model.pixels + " pixels of a " + view.model.width + " x " + view.model.height + " grid."
          : "Relighting view: this browser draws neither WebGL nor a 2-D canvas.";
      }
    }
  }

  function pick(key) {
    var view = key === undefined ? views[Object.keys(views)[0]] : views[key];
    if (!view) throw new Error("psrig relight: no view " + (key === undefined ? "on this page" : key));
    return view;
  }

  window.psrigRelight = {
    views: views,
    setLight: function (x, y, z, key) { var v = pick(key); v.setLight(x, y, z); return v.light; },
    setMode: function (mode, key) { pick(key).setMode(mode); },
    setExposure: function (stops, key) { var v = pick(key); v.exposure = stops; v.draw(); }
  };

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
