// Ticks a BehaviorTree.CPP XML tree with scripted leaves and prints what happened, for the
// differential tests in tests/interop/test_btcpp_engine.py (which print LiveTree's run the same
// way).
//
//   harness TREE.xml SCRIPT
//
// SCRIPT, one declaration a line:
//   ticks N                          how many times to tick the root
//   c NAME OUTCOMES PORT:TYPE ...    a condition; OUTCOMES is S/F per tick, cycled
//   a NAME OUTCOMES PORT:TYPE ...    an action; OUTCOMES is S/F/R per tick, cycled
//   set KEY TEXT                     the blackboard entry KEY, a string: TEXT, the rest of
//                                    the line (a port whose attribute is {KEY} reads it)
// TYPE is int, double, bool or string (the type the TreeNodesModel declares, string if none).
//
// Output, per tick: "tick K", then one line per leaf call ("call NAME port=value ...", the
// ports the node has, by name; values as the node reads them: ints in decimal, doubles %.17g,
// booleans true/false, strings as JSON) and per halted action ("halt NAME"), then
// "status STATUS"; then "halt tree" and what halting the whole tree halted. An error prints
// "error MESSAGE" and exits with status 2.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "behaviortree_cpp/action_node.h"
#include "behaviortree_cpp/bt_factory.h"
#include "behaviortree_cpp/condition_node.h"
#include "ktbt_btcpp.hpp"

namespace
{

struct Leaf
{
  std::string outcomes;
  std::vector<std::pair<std::string, std::string>> ports;  // name, type
};

unsigned current_tick = 0;

std::string json(const std::string& text)
{
  std::string out = "\"";
  for(unsigned char c : text)
  {
    switch(c)
    {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      case '\b': out += "\\b"; break;
      case '\f': out += "\\f"; break;
      default:
        if(c < 0x20)
        {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04x", c);
          out += buf;
        }
        else
        {
          out += char(c);
        }
    }
  }
  return out + "\"";
}

template <typename T>
T input(const BT::TreeNode& node, const std::string& port)
{
  auto value = node.getInput<T>(port);
  if(!value)
  {
    throw BT::RuntimeError(node.registrationName(), ": port ", port, ": ", value.error());
  }
  return value.value();
}

std::string callLine(const BT::TreeNode& node, const Leaf& leaf)
{
  std::string line = "call " + node.registrationName();
  for(const auto& [port, type] : leaf.ports)
  {
    if(node.config().input_ports.count(port) == 0)
    {
      continue;
    }
    std::string shown;
    if(type == "int")
    {
      shown = std::to_string(input<int>(node, port));
    }
    else if(type == "double")
    {
      char buf[40];
      std::snprintf(buf, sizeof buf, "%.17g", input<double>(node, port));
      shown = buf;
    }
    else if(type == "bool")
    {
      shown = input<bool>(node, port) ? "true" : "false";
    }
    else
    {
      shown = json(input<std::string>(node, port));
    }
    line += " " + port + "=" + shown;
  }
  return line;
}

BT::NodeStatus outcome(const Leaf& leaf)
{
  switch(leaf.outcomes[(current_tick - 1) % leaf.outcomes.size()])
  {
    case 'S': return BT::NodeStatus::SUCCESS;
    case 'F': return BT::NodeStatus::FAILURE;
    default: return BT::NodeStatus::RUNNING;
  }
}

class ScriptedCondition : public BT::ConditionNode
{
public:
  ScriptedCondition(const std::string& name, const BT::NodeConfig& config, const Leaf* leaf)
    : BT::ConditionNode(name, config), leaf_(leaf)
  {}

  BT::NodeStatus tick() override
  {
    std::cout << callLine(*this, *leaf_) << "\n";
    return outcome(*leaf_);
  }

private:
  const Leaf* leaf_;
};

class ScriptedAction : public BT::StatefulActionNode
{
public:
  ScriptedAction(const std::string& name, const BT::NodeConfig& config, const Leaf* leaf)
    : BT::StatefulActionNode(name, config), leaf_(leaf)
  {}

  BT::NodeStatus onStart() override
  {
    return onRunning();
  }

  BT::NodeStatus onRunning() override
  {
    std::cout << callLine(*this, *leaf_) << "\n";
    return outcome(*leaf_);
  }

  void onHalted() override
  {
    std::cout << "halt " << registrationName() << "\n";
  }

private:
  const Leaf* leaf_;
};

template <typename Node>
void registerLeaf(BT::BehaviorTreeFactory& factory, const std::string& name, const Leaf* leaf,
                  BT::NodeType type)
{
  BT::TreeNodeManifest manifest;
  manifest.type = type;
  manifest.registration_ID = name;
  for(const auto& [port, kind] : leaf->ports)
  {
    if(kind == "int")
    {
      manifest.ports.insert(BT::InputPort<int>(port));
    }
    else if(kind == "double")
    {
      manifest.ports.insert(BT::InputPort<double>(port));
    }
    else if(kind == "bool")
    {
      manifest.ports.insert(BT::InputPort<bool>(port));
    }
    else
    {
      manifest.ports.insert(BT::InputPort<std::string>(port));
    }
  }
  factory.registerBuilder(manifest, [leaf](const std::string& id, const BT::NodeConfig& config) {
    return std::make_unique<Node>(id, config, leaf);
  });
}

}  // namespace

int main(int argc, char** argv)
{
  if(argc != 3)
  {
    std::cerr << "usage: harness TREE.xml SCRIPT\n";
    return 2;
  }
  try
  {
    std::ifstream script(argv[2]);
    std::map<std::string, Leaf> leaves;
    std::vector<std::pair<char, std::string>> order;
    auto blackboard = BT::Blackboard::create();
    unsigned ticks = 0;
    std::string line;
    while(std::getline(script, line))
    {
      std::istringstream words(line);
      std::string kind, name;
      words >> kind;
      if(kind == "ticks")
      {
        words >> ticks;
        continue;
      }
      if(kind == "set")
      {
        std::string key, text;
        words >> key;
        std::getline(words >> std::ws, text);
        blackboard->set<std::string>(key, text);
        continue;
      }
      if(kind != "c" && kind != "a")
      {
        continue;
      }
      Leaf leaf;
      words >> name >> leaf.outcomes;
      std::string port;
      while(words >> port)
      {
        const auto colon = port.find(':');
        leaf.ports.emplace_back(port.substr(0, colon), port.substr(colon + 1));
      }
      std::sort(leaf.ports.begin(), leaf.ports.end());
      leaves[name] = leaf;
      order.emplace_back(kind[0], name);
    }
    BT::BehaviorTreeFactory factory;
    ktbt::registerNodes(factory);
    for(const auto& [kind, name] : order)
    {
      const Leaf* leaf = &leaves.at(name);
      if(kind == 'c')
      {
        registerLeaf<ScriptedCondition>(factory, name, leaf, BT::NodeType::CONDITION);
      }
      else
      {
        registerLeaf<ScriptedAction>(factory, name, leaf, BT::NodeType::ACTION);
      }
    }
    auto tree = factory.createTreeFromFile(std::filesystem::absolute(argv[1]), blackboard);
    for(current_tick = 1; current_tick <= ticks; ++current_tick)
    {
      std::cout << "tick " << current_tick << "\n";
      const BT::NodeStatus status = tree.tickExactlyOnce();
      std::cout << "status " << BT::toStr(status) << "\n";
    }
    std::cout << "halt tree\n";
    tree.haltTree();
    std::cout.flush();
  }
  catch(const std::exception& err)
  {
    std::cout << "error " << err.what() << std::endl;
    return 2;
  }
  return 0;
}
