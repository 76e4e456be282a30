// YOLOv8 stem on the CPU: y = SiLU(conv3x3/2(x, w) + b) for a 3-channel NHWC float32 image.
//
// XLA:CPU runs this convolution through Eigen's generic spatial convolution, which packs 27-wide
// patches and is ~3-4x slower than oneDNN on a 3-channel input (docs/detector.md). Here each output
// pixel keeps its CO accumulators in vector registers and adds the 27 taps (3 rows x 3 columns x 3
// channels) directly; bias and SiLU are applied before the store. Rows are shared out over XLA's
// own intra-op thread pool (the FFI ThreadPool), so no extra threads spin after the call.
//
// Layouts: x (B, H, W, 3), w (3, 3, 3, CO) (HWIO), b (CO), y (B, ceil(H/2), ceil(W/2), CO);
// padding 1 on every side (ultralytics Conv(k=3, s=2, p=1)).
// Built at first use by privslam_jax/detect/rgb_stem.py; registered as the XLA FFI target
// "privslam_rgb_stem".

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <memory>
#include <thread>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// One output pixel at (oy, ox); `inside`: all nine taps lie in the image (no bounds checks).
template <int CO, bool inside>
inline void Pixel(const float* x, const float* w, const float* b, float* y, int64_t H, int64_t W,
                  int64_t oy, int64_t ox) {
  float acc[CO];
#pragma omp simd
  for (int o = 0; o < CO; ++o) acc[o] = b[o];
#pragma GCC unroll 3
  for (int ky = 0; ky < 3; ++ky) {
    const int64_t iy = 2 * oy + ky - 1;
    if (!inside && (iy < 0 || iy >= H)) continue;
#pragma GCC unroll 3
    for (int kx = 0; kx < 3; ++kx) {
      const int64_t ix = 2 * ox + kx - 1;
      if (!inside && (ix < 0 || ix >= W)) continue;
      const float* px = x + (iy * W + ix) * 3;
      const float* pw = w + (ky * 3 + kx) * 3 * CO;
#pragma GCC unroll 3
      for (int c = 0; c < 3; ++c) {
        const float v = px[c];
#pragma omp simd
        for (int o = 0; o < CO; ++o) acc[o] += v * pw[c * CO + o];
      }
    }
  }
  // SiLU a·σ(a) with σ from e = e^-|a| in (0, 1]: σ = 1 / (1 + e) for a ≥ 0, e / (1 + e) below.
  // (a / (1 + e^-a) overflows to a / inf for a < -88.7, which fast-math's reciprocal turns into NaN.)
#pragma omp simd
  for (int o = 0; o < CO; ++o) {
    const float a = acc[o], e = std::exp(-std::fabs(a));
    y[o] = a * ((a >= 0.f ? 1.f : e) / (1.f + e));
  }
}

// Output rows [r0, r1) of one image.
template <int CO>
void Rows(const float* x, const float* w, const float* b, float* y, int64_t H, int64_t W,
          int64_t Wo, int64_t r0, int64_t r1) {
  // Columns 1 .. right-1 have all taps inside; the last column does only when W is even.
  const int64_t right = (2 * (Wo - 1) + 1 < W) ? Wo : Wo - 1;
  for (int64_t oy = r0; oy < r1; ++oy) {
    float* yr = y + oy * Wo * CO;
    if (oy < 1 || 2 * oy + 1 >= H) {
      for (int64_t ox = 0; ox < Wo; ++ox) Pixel<CO, false>(x, w, b, yr + ox * CO, H, W, oy, ox);
      continue;
    }
    Pixel<CO, false>(x, w, b, yr, H, W, oy, 0);
    for (int64_t ox = 1; ox < right; ++ox) Pixel<CO, true>(x, w, b, yr + ox * CO, H, W, oy, ox);
    for (int64_t ox = std::max<int64_t>(right, 1); ox < Wo; ++ox)
      Pixel<CO, false>(x, w, b, yr + ox * CO, H, W, oy, ox);
  }
}

using RowsFn = void (*)(const float*, const float*, const float*, float*, int64_t, int64_t, int64_t,
                        int64_t, int64_t);

RowsFn RowsFor(int64_t co) {
  switch (co) {  // YOLOv8 stems: scale tiny 8, n 16, s 32, m 48, l 64, x 80 channels
    case 8: return &Rows<8>;
    case 16: return &Rows<16>;
    case 32: return &Rows<32>;
    case 48: return &Rows<48>;
    case 64: return &Rows<64>;
    case 80: return &Rows<80>;
    default: return nullptr;
  }
}

struct Progress {
  std::atomic<int64_t> next{0}, done{0};
};

ffi::Error RgbStem(ffi::ThreadPool pool, ffi::BufferR4<ffi::F32> x, ffi::BufferR4<ffi::F32> w,
                   ffi::BufferR1<ffi::F32> b, ffi::ResultBufferR4<ffi::F32> y) {
  const auto xd = x.dimensions(), wd = w.dimensions(), yd = y->dimensions();
  const int64_t B = xd[0], H = xd[1], W = xd[2], Ho = yd[1], Wo = yd[2], CO = yd[3];
  if (xd[3] != 3 || wd[0] != 3 || wd[1] != 3 || wd[2] != 3 || wd[3] != CO || b.dimensions()[0] != CO ||
      yd[0] != B || Ho != (H + 1) / 2 || Wo != (W + 1) / 2)
    return ffi::Error::InvalidArgument("privslam_rgb_stem: shapes do not match x (B,H,W,3), w (3,3,3,CO)");
  const RowsFn rows = RowsFor(CO);
  if (rows == nullptr) return ffi::Error::InvalidArgument("privslam_rgb_stem: unsupported output channels");
  const float* xp = x.typed_data();
  const float* wp = w.typed_data();
  const float* bp = b.typed_data();
  float* yp = y->typed_data();

  // Chunks of 8 rows, claimed with an atomic counter by this thread and by helpers on XLA's pool.
  // The call returns once every claimed chunk is done; a helper that starts late finds nothing left.
  const int64_t chunk = 8, per_image = (Ho + chunk - 1) / chunk, total = B * per_image;
  auto progress = std::make_shared<Progress>();
  auto work = [=]() {
    for (int64_t i; (i = progress->next.fetch_add(1)) < total;) {
      const int64_t bi = i / per_image, r0 = (i % per_image) * chunk, r1 = std::min(Ho, r0 + chunk);
      rows(xp + bi * H * W * 3, wp, bp, yp + bi * Ho * Wo * CO, H, W, Wo, r0, r1);
      progress->done.fetch_add(1);
    }
  };
  const int64_t helpers = std::min<int64_t>(pool.num_threads(), total) - 1;
  for (int64_t t = 0; t < helpers; ++t) pool.Schedule([work]() { work(); });
  work();
  while (progress->done.load() < total) std::this_thread::yield();
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(PrivslamRgbStem, RgbStem,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Arg<ffi::BufferR4<ffi::F32>>()
                                  .Arg<ffi::BufferR4<ffi::F32>>()
                                  .Arg<ffi::BufferR1<ffi::F32>>()
                                  .Ret<ffi::BufferR4<ffi::F32>>());
