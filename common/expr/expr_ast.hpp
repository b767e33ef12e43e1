#pragma once
// Syntax tree of a parsed expression, stored in an arena (indices, no owning pointers).
// Left-associative runs of one precedence level (a + b - c + ...) are a single `chain`
// node, so the tree's height is bounded by the nesting depth, not by the length of the
// text: every later pass may recurse without risking the stack.
#include <cstdint>
#include <vector>

#include "common/expr/expr_ops.hpp"

namespace tally::expr {

using NodeId = uint32_t;

enum class NodeKind : uint8_t {
  constant,  // value
  variable,  // var
  unary,     // op(kids[0])
  binary,    // op(kids[0], kids[1]) (power, atan2)
  chain,     // kids[0] ops[0] kids[1] ops[1] kids[2] ..., evaluated left to right
  select,    // kids[0] ? kids[1] : kids[2]
};

struct Node {
  NodeKind kind = NodeKind::constant;
  Op op = Op::add;
  double value = 0;
  uint32_t var = 0;
  size_t position = 0;  // where the node's text starts (for messages)
  std::vector<NodeId> kids;
  std::vector<Op> ops;  // chain only: ops.size() == kids.size() - 1
};

struct Ast {
  std::vector<Node> nodes;
  NodeId root = 0;

  NodeId add(Node n) {
    nodes.push_back(std::move(n));
    return static_cast<NodeId>(nodes.size() - 1);
  }
  const Node& operator[](NodeId id) const { return nodes[id]; }
  Node& operator[](NodeId id) { return nodes[id]; }
};

}  // namespace tally::expr
