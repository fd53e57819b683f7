// KT-BT for BehaviorTree.CPP 4: the three nodes that `ktbt convert` writes and BT.CPP does not
// have, so a BT.CPP program can run any stringBT tree exported to XML.
//
//   #include "ktbt_btcpp.hpp"
//   BT::BehaviorTreeFactory factory;
//   ktbt::registerNodes(factory);        // KTBT_TT1, KTBT_TT2, KTBT_WaitTicks
//   ... register your own conditions and actions, then factory.createTreeFromFile(...)
//
// Header-only; it needs BehaviorTree.CPP 4 and C++17. The semantics are those of
// spec/stringbt.md, section 3.2, with the tree's own count of ticks as the tick clock (section
// 3.3): each node counts the ticks it receives in an activation, which is the tree's count,
// since a running node that is not ticked again is halted. An activation ends when the node
// returns SUCCESS or FAILURE or is halted; halting a timer halts its running child.
#pragma once

#include <cstdint>

#include "behaviortree_cpp/action_node.h"
#include "behaviortree_cpp/bt_factory.h"
#include "behaviortree_cpp/decorator_node.h"

namespace ktbt
{

/// Reads the `ticks` port once per activation; a missing or malformed count is an error.
inline unsigned readTicks(const BT::TreeNode& node)
{
  auto ticks = node.getInput<unsigned>("ticks");
  if(!ticks)
  {
    throw BT::RuntimeError(node.registrationName(), " [", node.name(),
                           "]: port 'ticks': ", ticks.error());
  }
  return ticks.value();
}

/// stringBT `<tt1>(N)`, the wait timer: RUNNING on ticks 1..N of an activation without ticking
/// the child, then the child's status. `<tt1>(0)` is its child.
class WaitTimer : public BT::DecoratorNode
{
public:
  WaitTimer(const std::string& name, const BT::NodeConfig& config)
    : BT::DecoratorNode(name, config)
  {}

  static BT::PortsList providedPorts()
  {
    return { BT::InputPort<unsigned>("ticks", "RUNNING for this many ticks, then the child's "
                                              "status") };
  }

  void halt() override
  {
    active_ = false;
    BT::DecoratorNode::halt();
  }

private:
  BT::NodeStatus tick() override
  {
    if(!active_)
    {
      limit_ = readTicks(*this);  // first: a count that cannot be read starts no activation
      waited_ = 0;
      active_ = true;
    }
    setStatus(BT::NodeStatus::RUNNING);
    if(waited_ < limit_)
    {
      ++waited_;
      return BT::NodeStatus::RUNNING;
    }
    const BT::NodeStatus status = child_node_->executeTick();
    if(status == BT::NodeStatus::RUNNING)
    {
      return status;
    }
    resetChild();
    active_ = false;
    return status;
  }

  bool active_ = false;
  unsigned waited_ = 0;
  unsigned limit_ = 0;
};

/// stringBT `<tt2>(N)`, the run timer: the child's status on ticks 1..N of an activation; a
/// child still RUNNING after its N-th tick is halted and the timer returns FAILURE on that same
/// tick. `<tt2>(0)` returns FAILURE without ticking the child.
class RunTimer : public BT::DecoratorNode
{
public:
  RunTimer(const std::string& name, const BT::NodeConfig& config)
    : BT::DecoratorNode(name, config)
  {}

  static BT::PortsList providedPorts()
  {
    return { BT::InputPort<unsigned>("ticks", "the child's status for this many ticks, then "
                                              "FAILURE") };
  }

  void halt() override
  {
    active_ = false;
    BT::DecoratorNode::halt();
  }

private:
  BT::NodeStatus tick() override
  {
    if(!active_)
    {
      limit_ = readTicks(*this);  // first: a count that cannot be read starts no activation
      ran_ = 0;
      active_ = true;
    }
    if(limit_ == 0)
    {
      active_ = false;
      return BT::NodeStatus::FAILURE;
    }
    setStatus(BT::NodeStatus::RUNNING);
    ++ran_;
    const BT::NodeStatus status = child_node_->executeTick();
    if(status != BT::NodeStatus::RUNNING)
    {
      resetChild();
      active_ = false;
      return status;
    }
    if(ran_ >= limit_)
    {
      haltChild();
      active_ = false;
      return BT::NodeStatus::FAILURE;
    }
    return status;
  }

  bool active_ = false;
  unsigned ran_ = 0;
  unsigned limit_ = 0;
};

/// stringBT `<w>(N)`: RUNNING on ticks 1..N of an activation, SUCCESS on tick N + 1.
class WaitTicks : public BT::StatefulActionNode
{
public:
  WaitTicks(const std::string& name, const BT::NodeConfig& config)
    : BT::StatefulActionNode(name, config)
  {}

  static BT::PortsList providedPorts()
  {
    return { BT::InputPort<unsigned>("ticks", "RUNNING for this many ticks, then SUCCESS") };
  }

  BT::NodeStatus onStart() override
  {
    limit_ = readTicks(*this);
    seen_ = 1;
    return step();
  }

  BT::NodeStatus onRunning() override
  {
    ++seen_;
    return step();
  }

  void onHalted() override
  {
    seen_ = 0;
  }

private:
  BT::NodeStatus step() const
  {
    return seen_ > limit_ ? BT::NodeStatus::SUCCESS : BT::NodeStatus::RUNNING;
  }

  std::uint64_t seen_ = 0;
  unsigned limit_ = 0;
};

/// Registers KTBT_TT1, KTBT_TT2 and KTBT_WaitTicks, the IDs `ktbt convert` writes.
inline void registerNodes(BT::BehaviorTreeFactory& factory)
{
  factory.registerNodeType<WaitTimer>("KTBT_TT1");
  factory.registerNodeType<RunTimer>("KTBT_TT2");
  factory.registerNodeType<WaitTicks>("KTBT_WaitTicks");
}

}  // namespace ktbt
