#pragma once
// How coarse a drag's images are: the pixel stride (a ray for every n-th pixel
// along x and y) chosen so that the view keeps up with the hand. A drag starts
// at the finest stride it is given; a view whose image took longer than the
// budget (1 / the rate aimed at) makes the next views twice as coarse, and
// three in a row that took under a quarter of it (a stride twice as fine has
// four times the rays) make them twice as fine again, never finer than the
// start. (One such view is not enough: a view's time also holds the frame
// update it waited for, and a single quick one made the stride go back and
// forth in the browser test.) The stride carries over from one drag to the
// next. The full image follows when the mouse stops, whatever the stride.
#include <algorithm>

namespace pp5::viewer {

class DragStride {
public:
  static constexpr int kCoarsest = 8;  // tiles are multiples of 8 pixels (live_view.cpp)
  static constexpr int kQuickViews = 3;  // views in a row under a quarter of the budget to refine
  // `finest`: 1, 2, 4 or 8; `rateHz` <= 0: always `finest`.
  DragStride(int finest, double rateHz)
      : finest_(finest), stride_(finest), budgetS_(rateHz > 0 ? 1.0 / rateHz : 0.0) {}

  int stride() const { return stride_; }

  // A drag's view rendered at `stride` took `seconds` (outputs/live_view: from its
  // message's arrival, or the last view's image if later, to its own image).
  // A view made at another stride than the current one (it was asked for
  // before the last change) says nothing about this one.
  void observe(int stride, double seconds) {
    if (budgetS_ <= 0 || stride != stride_) return;
    quick_ = 4 * seconds < budgetS_ ? std::min(quick_ + 1, kQuickViews) : 0;
    if (seconds > budgetS_) {
      stride_ = std::min(kCoarsest, stride_ * 2);
    } else if (quick_ >= kQuickViews && stride_ > finest_) {
      stride_ /= 2;
      quick_ = 0;
    }
  }

private:
  int finest_, stride_, quick_ = 0;
  double budgetS_;
};

}  // namespace pp5::viewer
