#pragma once
// Private to report/: the page of one run: verdict, expectations, plots, methods,
// closed-loop flights, figures, renders, collisions, sensors, decisions, metrics and the
// resolved scenario.

#include "report/html_inputs.h"
#include "report/html_page.h"

namespace tofu::report::html {

/// Writes <ctx.page_dir>/index.html (media/ beside it when images are large or clips).
void WriteRunPage(const RunInputs& in, const PageContext& ctx);

}  // namespace tofu::report::html
