// Scripted leaves for the example BehaviorTree.CPP programs (learner.cpp, nav2_loader.cpp):
// each condition and action a document's <TreeNodesModel> declares, registered with the ports
// the model gives it (int, double and bool ports are read as such, any other as text). A
// scripted action prints its call ("call NAME port=value ...") and succeeds; a scripted
// condition holds when the program's --true set names it, alone or with its ports as an
// action's call prints them. A port that does not read as its type fails the node and says
// why ("failure NAME: WHY").
#pragma once

#include <iostream>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "behaviortree_cpp/bt_factory.h"
#include "tinyxml2/tinyxml2.h"  // BehaviorTree.CPP's own parser, which its library exports

namespace ktbt_scripted
{

inline void say(const std::string& line)
{
  std::cout << line << std::endl;  // one flushed line each: a watcher reads them as they come
}

/// A condition or action the control document's <TreeNodesModel> declares, with its ports
/// (name and type) in the model's order.
struct Leaf
{
  std::string kind, id;
  std::vector<std::pair<std::string, std::string>> ports;
};

/// The conditions and actions of the document's <TreeNodesModel>, if it has one.
inline std::vector<Leaf> readModel(const std::string& xml)
{
  tinyxml2::XMLDocument doc;
  if(doc.Parse(xml.c_str(), xml.size()) != tinyxml2::XML_SUCCESS)
  {
    throw std::runtime_error(std::string("control tree: ") + doc.ErrorStr());
  }
  std::vector<Leaf> leaves;
  const auto* root = doc.RootElement();
  const auto* model = root ? root->FirstChildElement("TreeNodesModel") : nullptr;
  for(auto* node = model ? model->FirstChildElement() : nullptr; node;
      node = node->NextSiblingElement())
  {
    const std::string kind = node->Name();
    if((kind != "Condition" && kind != "Action") || node->Attribute("ID") == nullptr)
    {
      continue;  // decorators and controls: KT-BT's timers, registered from ktbt_btcpp.hpp
    }
    Leaf leaf{ kind, node->Attribute("ID"), {} };
    for(auto* port = node->FirstChildElement("input_port"); port;
        port = port->NextSiblingElement("input_port"))
    {
      if(port->Attribute("name") != nullptr)
      {
        const char* type = port->Attribute("type");
        leaf.ports.emplace_back(port->Attribute("name"), type ? type : "");
      }
    }
    leaves.push_back(std::move(leaf));
  }
  return leaves;
}

inline std::pair<std::string, BT::PortInfo> inputPort(const std::string& name, const std::string& type)
{
  if(type == "int")
    return BT::InputPort<int>(name);
  if(type == "double")
    return BT::InputPort<double>(name);
  if(type == "bool")
    return BT::InputPort<bool>(name);
  return BT::InputPort<std::string>(name);
}

/// Why the port does not read as a T, or nothing.
template <typename T>
std::string unread(BT::TreeNode& node, const std::string& name)
{
  auto value = node.getInput<T>(name);
  return value ? std::string() : value.error();
}

/// "NAME port=value ...": the call as the leaf's ports give it, or false (and the node says
/// why) when a port does not read as its type.
inline bool callOf(BT::TreeNode& node, const Leaf& leaf, std::string& call)
{
  call = leaf.id;
  for(const auto& [name, type] : leaf.ports)
  {
    std::string why = type == "int"    ? unread<int>(node, name) :
                      type == "double" ? unread<double>(node, name) :
                      type == "bool"   ? unread<bool>(node, name) :
                                         std::string();
    auto text = node.getInput<std::string>(name);
    if(why.empty() && !text)
    {
      why = text.error();
    }
    if(!why.empty())
    {
      say("failure " + leaf.id + ": " + why);
      return false;
    }
    call += " " + name + "=" + text.value();
  }
  return true;
}

/// Each of `leaves` the factory does not have yet, as a scripted leaf: an action prints its
/// call and succeeds, a condition holds when `holding` (which outlives the factory) names it
/// alone or with its ports.
inline void registerScripted(BT::BehaviorTreeFactory& factory, const std::vector<Leaf>& leaves,
                             const std::set<std::string>& holding)
{
  for(const Leaf& leaf : leaves)
  {
    if(factory.manifests().count(leaf.id) != 0)
    {
      continue;  // a compiled-in node (or a built-in one) keeps its own behaviour
    }
    BT::PortsList ports;
    for(const auto& [name, type] : leaf.ports)
    {
      ports.insert(inputPort(name, type));
    }
    if(leaf.kind == "Condition")
    {
      factory.registerSimpleCondition(
          leaf.id,
          [leaf, &holding](BT::TreeNode& node) {
            std::string call;
            const bool holds = callOf(node, leaf, call) &&
                               (holding.count(leaf.id) != 0 || holding.count(call) != 0);
            return holds ? BT::NodeStatus::SUCCESS : BT::NodeStatus::FAILURE;
          },
          ports);
    }
    else
    {
      factory.registerSimpleAction(
          leaf.id,
          [leaf](BT::TreeNode& node) {
            std::string call;
            if(!callOf(node, leaf, call))
            {
              return BT::NodeStatus::FAILURE;
            }
            say("call " + call);
            return BT::NodeStatus::SUCCESS;
          },
          ports);
    }
  }
}

}  // namespace ktbt_scripted
