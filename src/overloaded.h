// Internal: one lambda per alternative of a std::variant, so that std::visit handles each kind
// in one place and the compiler refuses a visitor that forgets one:
//
//   std::visit(Overloaded{[](const AnalyticSphere& s) { ... },
//                         [](const AnalyticBox& b) { ... },
//                         [](const LevelSetPtr& ls) { ... }},
//              shape);
#pragma once

namespace penumbra {

template <class... Fs>
struct Overloaded : Fs... {
    using Fs::operator()...;
};
template <class... Fs>
Overloaded(Fs...) -> Overloaded<Fs...>;

}  // namespace penumbra
