// A stand-in for an image module built against another layout of the table's types (a copied
// program finding an older build tree's module): the right version, the wrong layout. Loaded
// only by tests/test_image_io.cpp, which expects it refused by name.
#include "image_backend.h"

namespace {

const penumbra::detail::ImageBackend kStale{penumbra::detail::kImageBackendVersion,
                                            penumbra::detail::kImageBackendLayout + 1, nullptr,
                                            nullptr, nullptr};

}  // namespace

extern "C" const penumbra::detail::ImageBackend* penumbra_image_backend() { return &kStale; }
