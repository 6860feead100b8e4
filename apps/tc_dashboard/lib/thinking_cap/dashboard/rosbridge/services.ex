defmodule ThinkingCap.Dashboard.Rosbridge.Services do
  @moduledoc false
  # The services rosbridge answers: a subset of ROS 2's rosapi, enough for
  # clients to discover the topics and pick ROS 2 parsing. Each takes the
  # call's `args` (an object, or a list in the fields' order) and the
  # topics served, and returns the response's `values` or an error text.

  alias ThinkingCap.Dashboard.Rosbridge.Definitions

  @ros_version 2
  @distro "humble"

  # name => {type, request fields}
  @services %{
    "/rosapi/topics" => {"rosapi_msgs/srv/Topics", []},
    "/rosapi/topics_for_type" => {"rosapi_msgs/srv/TopicsForType", ["type"]},
    "/rosapi/topic_type" => {"rosapi_msgs/srv/TopicType", ["topic"]},
    "/rosapi/topics_and_raw_types" => {"rosapi_msgs/srv/TopicsAndRawTypes", []},
    "/rosapi/services" => {"rosapi_msgs/srv/Services", []},
    "/rosapi/service_type" => {"rosapi_msgs/srv/ServiceType", ["service"]},
    "/rosapi/nodes" => {"rosapi_msgs/srv/Nodes", []},
    "/rosapi/get_ros_version" => {"rosapi_msgs/srv/GetROSVersion", []},
    "/rosapi/get_time" => {"rosapi_msgs/srv/GetTime", []}
  }

  @doc "The names of the services."
  @spec names() :: [String.t()]
  def names, do: @services |> Map.keys() |> Enum.sort()

  @doc "The ROS version and distribution rosbridge reports."
  @spec ros_version() :: {pos_integer(), String.t()}
  def ros_version, do: {@ros_version, @distro}

  @doc "Calls service `name` with `args`; `topics` are the `{name, type}` served."
  @spec call(String.t(), term(), [{String.t(), String.t()}]) ::
          {:ok, map()} | {:error, String.t()}
  def call(name, args, topics) do
    case @services[name] do
      nil ->
        {:error, "Service #{name} does not exist"}

      {_type, fields} ->
        with {:ok, args} <- arguments(args, fields), do: answer(name, args, topics)
    end
  end

  defp arguments(nil, _fields), do: {:ok, %{}}
  defp arguments(args, _fields) when is_map(args), do: {:ok, args}

  defp arguments(args, fields) when is_list(args) and length(args) <= length(fields),
    do: {:ok, fields |> Enum.zip(args) |> Map.new()}

  defp arguments(args, _fields),
    do: {:error, "service arguments must be an object, not #{inspect(args, limit: 5)}"}

  defp answer("/rosapi/topics", _args, topics) do
    {names, types} = Enum.unzip(topics)
    {:ok, %{topics: names, types: types}}
  end

  defp answer("/rosapi/topics_for_type", args, topics) do
    with {:ok, type} <- string(args, "type") do
      short = Definitions.short(type)
      {:ok, %{topics: for({n, t} <- topics, Definitions.short(t) == short, do: n)}}
    end
  end

  defp answer("/rosapi/topic_type", args, topics) do
    with {:ok, topic} <- string(args, "topic") do
      topic = if String.starts_with?(topic, "/"), do: topic, else: "/" <> topic
      {:ok, %{type: Enum.find_value(topics, "", fn {n, t} -> n == topic && t end)}}
    end
  end

  defp answer("/rosapi/topics_and_raw_types", _args, topics) do
    {names, types} = Enum.unzip(topics)

    {:ok,
     %{topics: names, types: types, typedefs_full_text: Enum.map(types, &Definitions.full_text/1)}}
  end

  defp answer("/rosapi/services", _args, _topics), do: {:ok, %{services: names()}}

  defp answer("/rosapi/service_type", args, _topics) do
    with {:ok, service} <- string(args, "service") do
      service = if String.starts_with?(service, "/"), do: service, else: "/" <> service

      case @services[service] do
        {type, _} -> {:ok, %{type: type}}
        nil -> {:ok, %{type: ""}}
      end
    end
  end

  defp answer("/rosapi/nodes", _args, _topics), do: {:ok, %{nodes: ["/thinking_cap/rosbridge"]}}

  defp answer("/rosapi/get_ros_version", _args, _topics),
    do: {:ok, %{version: @ros_version, distro: @distro}}

  defp answer("/rosapi/get_time", _args, _topics) do
    ns = System.os_time(:nanosecond)
    {:ok, %{time: %{sec: div(ns, 1_000_000_000), nanosec: rem(ns, 1_000_000_000)}}}
  end

  defp string(args, key) do
    case Map.get(args, key) do
      s when is_binary(s) -> {:ok, s}
      nil -> {:error, "argument #{key} is required"}
      other -> {:error, "argument #{key} must be a string, not #{inspect(other, limit: 5)}"}
    end
  end
end
